"""valve_bringup: what starts the whole valve suite.

The top of the package graph (``valve_msgs <- valve_model_pkg <- valve_driver_pkg <-
valve_bringup``): the demo (``valve_demo``), the loop through the bench
(``valve_bench_loop``), the process supervisor they share, the CAN backend as processes,
and the suite launch file. Nothing below imports it.
"""
