"""ROS-free stand-in devices for tests and the demo, written from the standards and the
products' manuals (not from the driver): a CiA 401 output module (``valve_canopen_device``),
an ISO 11783-7 auxiliary valve (``valve_j1939_device``) and a user's board driven by its own
DBC (``valve_dbc_device``). Each runs the suite's valve model behind its output."""
