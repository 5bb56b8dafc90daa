# Source this file (bash or zsh) to get a shell in which every node and command of the
# valve suite runs:   source ros2_ws/env.bash
# It activates the project venv (which is also the ROS 2 Jazzy prefix), overlays the built
# colcon workspace, puts the suite's console scripts on PATH and keeps DDS traffic on this
# machine. Run `make setup` first (make demo / make test do it for you).

if [ -n "${BASH_SOURCE[0]:-}" ]; then
  _valve_ws="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
else
  _valve_ws="$(cd "$(dirname "$0")" && pwd)"  # zsh
fi
_valve_root="$(dirname "$_valve_ws")"
_valve_venv="${VALVE_VENV:-$_valve_root/.venv}"

if [ ! -x "$_valve_venv/bin/python" ] || [ ! -f "$_valve_ws/install/setup.bash" ]; then
  echo "valve suite: not set up yet; run 'make setup' in $_valve_root first" >&2
  unset _valve_ws _valve_root _valve_venv
  return 1 2>/dev/null || exit 1
fi

export VIRTUAL_ENV="$_valve_venv"
case ":$PATH:" in *":$_valve_venv/bin:"*) ;; *) export PATH="$_valve_venv/bin:$PATH" ;; esac
# The venv is the ROS prefix of the pip-installed Jazzy wheels.
export AMENT_PREFIX_PATH="$_valve_venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$_valve_venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
# colcon's setup scripts read unset variables: relax nounset while sourcing them, so this
# file also works from `set -u` shells and Makefiles.
case "$-" in *u*) _valve_nounset=1; set +u ;; *) _valve_nounset= ;; esac
# shellcheck disable=SC1091
. "$_valve_ws/install/setup.bash"
[ -z "$_valve_nounset" ] || set -u
# ament_python installs console scripts in lib/<pkg> (for `ros2 run`); put them on PATH too
# so `valve_simulator` works without the ros2 CLI, which the wheels do not provide.
for _valve_pkg in valve_model_pkg valve_driver_pkg valve_bringup; do
  case ":$PATH:" in
    *":$_valve_ws/install/$_valve_pkg/lib/$_valve_pkg:"*) ;;
    *) export PATH="$_valve_ws/install/$_valve_pkg/lib/$_valve_pkg:$PATH" ;;
  esac
done
# DDS stays on this machine (docs/safety.md, "Network"): the Fast DDS profile binds every
# socket to 127.0.0.1 and uses no multicast. The range is SYSTEM_DEFAULT because with
# LOCALHOST rmw_fastrtps adds its own UDP transport, which binds 0.0.0.0 and the machine's
# addresses whatever the profile says. SKIP_DEFAULT_XML_FILE: a DEFAULT_FASTRTPS_PROFILES.xml
# in the working directory cannot override the profile.
# Multi-machine use is opt-in: `VALVE_SUITE_MULTI_MACHINE=1 source ros2_ws/env.bash` gives
# plain ROS 2 behaviour (discovery by multicast on the subnet, sockets on all interfaces).
if [ "${VALVE_SUITE_MULTI_MACHINE:-0}" = 1 ]; then
  if [ "${FASTRTPS_DEFAULT_PROFILES_FILE:-}" = "$_valve_ws/fastdds_localhost.xml" ]; then
    unset FASTRTPS_DEFAULT_PROFILES_FILE FASTDDS_DEFAULT_PROFILES_FILE SKIP_DEFAULT_XML_FILE
  fi
  export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
else
  export FASTRTPS_DEFAULT_PROFILES_FILE="$_valve_ws/fastdds_localhost.xml"  # Fast DDS 2.x
  export FASTDDS_DEFAULT_PROFILES_FILE="$FASTRTPS_DEFAULT_PROFILES_FILE"    # Fast DDS 3.x
  export SKIP_DEFAULT_XML_FILE=1
  export ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT
fi
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-42}"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export VALVE_SUITE_ROOT="$_valve_root"
unset _valve_ws _valve_root _valve_venv _valve_pkg _valve_nounset
