#!/usr/bin/env bash
# Set up the abp workspace on this machine and build it with colcon into install/.
#
#   scripts/bootstrap.sh            # idempotent: a second run with nothing changed takes seconds
#   ABP_FORCE_BUILD=1 scripts/bootstrap.sh   # rebuild even when the sources look unchanged
#
# Where /opt/ros/jazzy exists (a robot, a ROS Docker image) it uses that ROS and
# installs only the few extra Python packages (requirements/robot.txt, pinned to keep
# Ubuntu 24.04's NumPy 1.26) into a --system-site-packages venv, then builds with
# that venv's Python so every entry point runs with it. Otherwise
# it creates .venv/ from the pinned ROS 2 Jazzy wheels on PyPI
# (requirements/requirements.txt + requirements/constraints.txt) and applies the
# fixes those wheels need (see shared/ROS_WHEELS.md).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
REQ_DIR="$REPO/requirements"
ROS_DISTRO_DIR="/opt/ros/jazzy"
PACKAGES=(abp_msgs abp_common abp_description abp_belief abp_planner abp_perception abp_skills abp_sim_bridge
          abp_bringup abp_bench)
# Message packages the PyPI wheels lack (vendor/README.md); a robot's ROS already has them.
VENDORED=(vendor/control_msgs vendor/tf2_msgs)

log() { printf '[bootstrap] %s\n' "$*" >&2; }
die() { printf '[bootstrap] error: %s\n' "$*" >&2; exit 1; }

sha_of_files() { cat "$@" | sha256sum | cut -d' ' -f1; }

# --- platform checks -------------------------------------------------------
arch="$(uname -m)"
case "$arch" in
  x86_64|aarch64) ;;
  *) die "unsupported architecture '$arch': the ROS 2 Jazzy wheels exist for x86_64 and aarch64 only" ;;
esac

if [ -d "$ROS_DISTRO_DIR" ]; then
  USE_SYSTEM_ROS=1
  PYTHON="${ABP_PYTHON:-/usr/bin/python3}"
else
  USE_SYSTEM_ROS=0
  PACKAGES+=("${VENDORED[@]}")
  PYTHON="${ABP_PYTHON:-}"
  if [ -z "$PYTHON" ]; then
    for candidate in python3.11 python3; do
      if command -v "$candidate" >/dev/null 2>&1; then PYTHON="$(command -v "$candidate")"; break; fi
    done
  fi
  [ -n "$PYTHON" ] || die "no python3 found; install CPython 3.11"
  pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
  [ "$pyver" = "3.11" ] || die "unsupported Python $pyver at $PYTHON: the ROS 2 Jazzy wheels on PyPI are built for CPython 3.11 only (set ABP_PYTHON to a python3.11)"
fi

# --- Python environment ----------------------------------------------------
env_stamp="$VENV/.abp-env-stamp"
if [ "$USE_SYSTEM_ROS" = 1 ]; then
  want_env="system-ros:$(sha_of_files "$REQ_DIR/robot.txt")"
else
  want_env="wheels:$(sha_of_files "$REQ_DIR/requirements.txt" "$REQ_DIR/constraints.txt")"
fi

if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$env_stamp" 2>/dev/null)" != "$want_env" ]; then
  if [ ! -x "$VENV/bin/python" ]; then
    log "creating $VENV with $PYTHON"
    if [ "$USE_SYSTEM_ROS" = 1 ]; then
      "$PYTHON" -m venv --system-site-packages "$VENV"
    else
      "$PYTHON" -m venv "$VENV"
    fi
  fi
  log "installing pinned Python packages (this takes a minute on a new machine)"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
    "pip==$(sed -n 's/^pip==//p' "$REQ_DIR/constraints.txt")"
  if [ "$USE_SYSTEM_ROS" = 1 ]; then
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$REQ_DIR/robot.txt"
  else
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
      -r "$REQ_DIR/requirements.txt" -c "$REQ_DIR/constraints.txt" \
      "setuptools==$(sed -n 's/^setuptools==//p' "$REQ_DIR/constraints.txt")"
    # Pitfall 1: the wheels' exported CMake files name the include paths of the
    # machine they were built on; point them at this interpreter and NumPy.
    "$VENV/bin/python" - "$VENV" <<'PY'
import pathlib, sys, sysconfig
import numpy
venv = pathlib.Path(sys.argv[1])
replacements = {
    "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include": numpy.get_include(),
    "/opt/python/cp311-cp311/include/python3.11": sysconfig.get_paths()["include"],
}
fixed = 0
for path in (venv / "share").rglob("*.cmake"):
    text = path.read_text()
    new = text
    for old, repl in replacements.items():
        new = new.replace(old, repl)
    if new != text:
        path.write_text(new)
        fixed += 1
print(f"[bootstrap] rewrote build-machine include paths in {fixed} CMake files", file=sys.stderr)
PY
  fi
  echo "$want_env" > "$env_stamp"
else
  log "Python environment up to date ($VENV)"
fi

# --- build -----------------------------------------------------------------
# Skip colcon when no package source changed since the last successful build:
# that is what makes a second run take seconds.
build_stamp="$REPO/install/.abp-build-stamp"
want_build="$want_env:$(cd "$REPO" && find "${PACKAGES[@]}" -type f \
  -not -path '*/__pycache__/*' -not -name '*.pyc' -not -path '*/test/*' -print0 \
  | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)"
if [ "${ABP_FORCE_BUILD:-0}" != 1 ] && [ "$(cat "$build_stamp" 2>/dev/null)" = "$want_build" ]; then
  log "workspace up to date (install/)"
  exit 0
fi

log "building ${PACKAGES[*]} with colcon"
cd "$REPO"
if [ "$USE_SYSTEM_ROS" = 1 ]; then
  # shellcheck disable=SC1091
  set +u; source "$ROS_DISTRO_DIR/setup.bash"; set -u
  export PATH="$VENV/bin:$PATH"
  # colcon writes its own interpreter (sys.executable) into every entry point's
  # shebang, so run apt's colcon with the venv's Python (the venv sees apt's packages
  # through --system-site-packages): `ros2 run` then starts the nodes with an
  # interpreter that imports both rclpy and the pinned packages of robot.txt. The apt
  # `colcon` script would write #!/usr/bin/python3, which cannot import cv2, ruckig,
  # rosbags or mujoco (ros2/ros2cli#1024).
  "$VENV/bin/python" -c 'import colcon_core' 2>/dev/null \
    || die "colcon is not importable from $VENV: sudo apt install python3-colcon-common-extensions"
  "$VENV/bin/python" -c 'import pinocchio' 2>/dev/null \
    || die "pinocchio is not importable: sudo apt install ros-jazzy-pinocchio (or rosdep install --from-paths abp_* --ignore-src -y); PyPI's pin needs NumPy 2 (requirements/robot.txt)"
  "$VENV/bin/python" -m colcon build --base-paths "${PACKAGES[@]}" --event-handlers console_direct- \
    --cmake-args -DBUILD_TESTING=OFF "-DPython3_EXECUTABLE=$VENV/bin/python"
else
  # Pitfall 2: CMake finds the wheels' share/ and lib/ through these prefixes.
  export AMENT_PREFIX_PATH="$VENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$VENV${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
  export PATH="$VENV/bin:$PATH"
  "$VENV/bin/colcon" build --base-paths "${PACKAGES[@]}" --event-handlers console_direct- \
    --cmake-args -DBUILD_TESTING=OFF "-DPython3_EXECUTABLE=$VENV/bin/python"
fi
echo "$want_build" > "$build_stamp"
log "done: source scripts/env.sh to use the workspace"
