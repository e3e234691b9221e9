# Source this file (bash or zsh) after scripts/bootstrap.sh:
#   source scripts/env.sh
# It gives a shell in which the abp packages import and their executables run:
# the ROS 2 environment (/opt/ros/jazzy when present, else the PyPI wheels in
# .venv/), then the workspace overlay in install/.
if [ -n "${BASH_SOURCE:-}" ]; then
  _abp_here="${BASH_SOURCE[0]}"
else
  _abp_here="${(%):-%x}"
fi
ABP_REPO="$(cd "$(dirname "$_abp_here")/.." && pwd)"
export ABP_REPO
unset _abp_here

if [ ! -f "$ABP_REPO/install/setup.sh" ]; then
  echo "[env.sh] $ABP_REPO/install is missing: run scripts/bootstrap.sh first" >&2
  return 1 2>/dev/null || exit 1
fi

if [ -d /opt/ros/jazzy ]; then
  # shellcheck disable=SC1091
  . /opt/ros/jazzy/setup.sh
else
  # The wheels install ROS's share/ and lib/ under the venv prefix.
  export AMENT_PREFIX_PATH="$ABP_REPO/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  export CMAKE_PREFIX_PATH="$ABP_REPO/.venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
fi
export VIRTUAL_ENV="$ABP_REPO/.venv"
export PATH="$ABP_REPO/.venv/bin:$PATH"
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
# MuJoCo renders headless through EGL; it reads MUJOCO_GL when it is first imported.
export MUJOCO_GL="${MUJOCO_GL:-egl}"
# colcon without colcon-bash writes the POSIX setup.sh only.
COLCON_CURRENT_PREFIX="$ABP_REPO/install" . "$ABP_REPO/install/setup.sh"
