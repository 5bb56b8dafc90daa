"""ROS-free device protocols of valve_can_driver (CANopen CiA 401, J1939 / ISO 11783-7, a
user's own DBC) and the driver core that runs them: see docs/controllers.md."""
