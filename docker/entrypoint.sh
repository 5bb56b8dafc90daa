#!/usr/bin/env bash
# Source ROS 2 and the suite's workspace, then run the command. Arguments that look like
# launch arguments (name:=value) are appended to the default launch command.
set -e
source /opt/ros/jazzy/setup.bash
source /ws/install/setup.bash
if [ "$#" -gt 0 ] && [[ "$1" == *":="* ]]; then
  exec ros2 launch valve_bringup valve_suite.launch.py "$@"
fi
exec "$@"
