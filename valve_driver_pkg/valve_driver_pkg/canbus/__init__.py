"""ROS-free CAN transport helpers: bus factory and the tcp_loopback hub/bus."""
from valve_driver_pkg.canbus.factory import LOCAL_INTERFACES, open_bus
from valve_driver_pkg.canbus.tcp_loopback import (DEFAULT_PORT, TcpLoopbackBus, TcpLoopbackHub,
                                                  parse_channel)

__all__ = ['open_bus', 'LOCAL_INTERFACES', 'TcpLoopbackBus', 'TcpLoopbackHub', 'parse_channel',
           'DEFAULT_PORT']
