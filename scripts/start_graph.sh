#!/usr/bin/env bash
# Start the whole abp graph, recognise the object in front of the robot, shut down.
#
#   scripts/start_graph.sh [options]
#
# By default it runs in simulation: the sim bridge stands in for the robot, with a
# seeded random hidden cube from the model set. It bootstraps first on a fresh
# machine, starts every node unconfigured (autostart:=false; with `ros2 run` where ros2
# is on PATH, else the same installed executables) and the lifecycle manager, which
# configures and activates them in order, waits for the manager's `graph ready` (every
# node active, every topic between them matched), sends a Recognize goal,
# prints the trace and the result, and stops every process (also on Ctrl-C).
#
# Options:
#   --robot              run on the robot: no sim bridge, no sim time
#   --world W            sim world: mujoco (physics, MuJoCo camera) | rules (contact rules,
#                        flat renderer; fast)                            (default mujoco)
#   --object N           hidden cube in sim: index into the model set (default: seeded random)
#   --objects K          cubes in the scene (sim: K models without repeats, seeded, >= 0.3 m
#                        apart; the first is --object's); K > 1 turns object tracking on in
#                        the aspect matcher (docs/MULTI_OBJECT.md)                (default 1)
#   --twins              sim, --objects >= 2: the first two cubes are eccentric mass twins
#   --models SET         robot | random:N | full | visual | path/to/models.npz  (default robot)
#   --tables T           hand-written ATG table of a generated set (docs/MODEL.md): corrected
#                        | paper (default paper in the rules world, whose physics it is, else
#                        corrected); a models file carries its own tables
#   --planner MODE       random | abp | abp2 | abp3 | cost                   (default cost)
#   --seed S             seed of the model set, the hidden cube and the sim  (default 0)
#   --robot-profile FILE the robot's profile YAML (docs/PORTING.md), given to every node; its
#                        learned ATG model set (`models:`) is the default of --models
#                        (default: the uBot-6, abp_description/profiles/ubot6.yaml)
#   --dictionary D       the cubes' ArUco dictionary, an OpenCV name: the detector reads it
#                        and the sim draws it, e.g. DICT_APRILTAG_36h11     (default DICT_4X4_50)
#   --params FILE        extra parameters YAML (/**/<node>: ros__parameters: ...), applied last
#   --namespace NS       run every node under the namespace /NS (topics, services, actions)
#   --record DIR         record the graph's topics to a rosbag2 (MCAP) bag in DIR
#   --record-images      with --record: also record camera/image_raw (large; for episode_report)
#   --result-json FILE   write the result (object, posterior, actions, time, ground truth)
#   --speedup X          sim time speed-up (default 10)
#   --max-actions N      action budget (default 30)
#   --timeout S          wall-clock limit of the recognition (default 1800)
#   --log-dir DIR        where node logs go (default log/graph-<time>)
#   --no-build           skip scripts/bootstrap.sh (use install/ as it is)
#   --no-respawn         do not restart a node that dies (by default a node that dies is
#                        restarted, unless it stopped cleanly, exited with a configuration
#                        error, or died 3 times within 10 s of starting)
#   --serve              start the graph and keep it up without sending a goal, until Ctrl-C
#                        or SIGTERM (for a driver that sends its own goals, e.g. abp_bench.soak)
#   --operator person    no robot, no sim: a person carries out each action, asked on this
#                        terminal (operator_skills instead of skill_servers; docs/OPERATOR.md);
#                        needs --camera and --calibration
#   --camera SRC         with --operator person: the camera node's source, a V4L2 device
#                        (/dev/video0), a video file or a folder of images (played in a loop)
#   --calibration FILE   with --camera: its camera_calibration YAML (calibrate_camera writes one)
#   --camera-pose "X Y Z ROLL PITCH YAW"   with --camera: where the camera stands, m and deg,
#                        camera x forward, z up, positive pitch looks down, in a frame on the
#                        table below it (x towards the cube)           (default "0 0 0.4 0 45 0")
#   --operator-terminal T  the operator's terminal device (default /dev/tty)
#   --operator scripted  no robot: a MuJoCo world with a fixed camera at --camera-pose and the
#                        hidden cube (--object, --seed), and a simulated person who reads each
#                        request on operator_skills' terminal (a pty), does it to the cube and
#                        answers (the scripted_operator node; docs/OPERATOR.md)
#   --wrong-action-fraction F  with --operator scripted: share of the requests the person
#                        carries out as another action (default 0)
#   --operator-silent    with --operator scripted: the person never answers (skill_timeout)
#   --one-process        run the managed nodes in one process on one executor
#                        (abp_bringup graph_container; docs/STARTUP.md): a node that dies
#                        takes the others with it, and the container is restarted as one
#   --part P             robot | workstation | all: start only this part of the graph, for a
#                        split over a network (docs/OFFBOARD.md; abp_common.graph_nodes):
#                        robot = sim bridge or drivers, perception, skills, serving until
#                        Ctrl-C like --serve; workstation = belief, planner, the lifecycle
#                        manager (it brings up the robot's nodes over the network) and the
#                        goal. Give both parts the same graph options.       (default all)
#   --perception-on P    robot | workstation: where the tag detector and the aspect matcher
#                        run when the graph is split (default robot). workstation: the
#                        detector reads camera/image_raw/compressed (JPEG, image_transport's
#                        compressed transport), which the sim bridge publishes (on a robot,
#                        its camera driver must); images cross the link
#   --jpeg-quality Q     with --perception-on workstation: the sim's JPEG quality (default 90)
#   --discovery-server HOST:PORT  DDS discovery through a Fast DDS discovery server instead
#                        of multicast (ROS_DISCOVERY_SERVER for every node); the part on the
#                        host that owns HOST starts the server there (fast-discovery-server)
#
# ROS_SECURITY_ENABLE=true (SROS2) is refused at start, naming why, when this machine's
# rmw cannot do DDS Security (the PyPI Fast DDS; abp_bringup.security_check).
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

robot=0; object=-1; objects=1; twins=false; models=robot; planner=cost; seed=0; params=""; record=""; result_json=""
speedup=10; max_actions=30; timeout=1800; log_dir=""; namespace=""; world=mujoco; build=1
tables=""; dictionary=""; robot_profile=""; models_given=0
respawn=1; serve=0; record_images=false; one_process=0; part=all
operator=""; camera=""; calibration=""; camera_pose="0 0 0.4 0 45 0"; operator_terminal=/dev/tty
perception_on=robot; jpeg_quality=""; discovery_server=""
wrong_action_fraction=""; operator_silent=false
usage() { sed -n '2,84p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
die() { echo "[start_graph] error: $*" >&2; exit 2; }
# A YAML single-quoted string (a path may hold any character; ' is written twice).
yaml_string() { printf "'%s'" "${1//\'/\'\'}"; }
while [ $# -gt 0 ]; do
  case "$1" in
    --robot) robot=1; shift ;;
    --world) world="${2:?--world needs a value}"; shift 2 ;;
    --no-build) build=0; shift ;;
    --no-respawn) respawn=0; shift ;;
    --serve) serve=1; shift ;;
    --one-process) one_process=1; shift ;;
    --part) part="${2:?--part needs a value}"; shift 2 ;;
    --perception-on) perception_on="${2:?--perception-on needs robot or workstation}"; shift 2 ;;
    --jpeg-quality) jpeg_quality="${2:?--jpeg-quality needs a value}"; shift 2 ;;
    --discovery-server) discovery_server="${2:?--discovery-server needs HOST:PORT}"; shift 2 ;;
    --object) object="${2:?--object needs a value}"; shift 2 ;;
    --objects) objects="${2:?--objects needs a value}"; shift 2 ;;
    --twins) twins=true; shift ;;
    --models) models="${2:?--models needs a value}"; models_given=1; shift 2 ;;
    --robot-profile) robot_profile="${2:?--robot-profile needs a file}"; shift 2 ;;
    --tables) tables="${2:?--tables needs a value}"; shift 2 ;;
    --planner) planner="${2:?--planner needs a value}"; shift 2 ;;
    --seed) seed="${2:?--seed needs a value}"; shift 2 ;;
    --dictionary) dictionary="${2:?--dictionary needs a value}"; shift 2 ;;
    --params) params="${2:?--params needs a file}"; shift 2 ;;
    --record) record="${2:?--record needs a directory}"; shift 2 ;;
    --record-images) record_images=true; shift ;;
    --result-json) result_json="${2:?--result-json needs a file}"; shift 2 ;;
    --speedup) speedup="${2:?--speedup needs a value}"; shift 2 ;;
    --max-actions) max_actions="${2:?--max-actions needs a value}"; shift 2 ;;
    --timeout) timeout="${2:?--timeout needs a value}"; shift 2 ;;
    --log-dir) log_dir="${2:?--log-dir needs a directory}"; shift 2 ;;
    --namespace) namespace="${2?--namespace needs a value}"; shift 2 ;;
    --operator) operator="${2:?--operator needs a value}"; shift 2 ;;
    --camera) camera="${2:?--camera needs a device or file}"; shift 2 ;;
    --calibration) calibration="${2:?--calibration needs a file}"; shift 2 ;;
    --camera-pose) camera_pose="${2:?--camera-pose needs X Y Z ROLL PITCH YAW}"; shift 2 ;;
    --operator-terminal) operator_terminal="${2:?--operator-terminal needs a device}"; shift 2 ;;
    --wrong-action-fraction) wrong_action_fraction="${2:?--wrong-action-fraction needs a value}"; shift 2 ;;
    --operator-silent) operator_silent=true; shift ;;
    -h|--help) usage; exit 0 ;;
    *) die "unknown option $1 (see --help)" ;;
  esac
done
[[ "$world" =~ ^(mujoco|rules)$ ]] || die "--world must be mujoco or rules"
[[ "$part" =~ ^(robot|workstation|all)$ ]] || die "--part must be robot, workstation or all"
[[ "$perception_on" =~ ^(robot|workstation)$ ]] || die "--perception-on must be robot or workstation"
if [ -n "$jpeg_quality" ]; then
  [ "$perception_on" = workstation ] || die "--jpeg-quality goes with --perception-on workstation"
  [[ "$jpeg_quality" =~ ^[0-9]+$ ]] && [ "$jpeg_quality" -ge 1 ] && [ "$jpeg_quality" -le 100 ] \
    || die "--jpeg-quality must be an integer from 1 to 100"
fi
[ "$perception_on" = robot ] || [ -z "$operator" ] \
  || die "--perception-on workstation splits the sim or robot graph: leave out --operator"
if [ -n "$discovery_server" ]; then
  [[ "$discovery_server" =~ ^([0-9]{1,3}(\.[0-9]{1,3}){3}|[A-Za-z0-9][A-Za-z0-9.-]*):([0-9]{1,5})$ ]] \
    && [ "${BASH_REMATCH[3]}" -ge 1 ] && [ "${BASH_REMATCH[3]}" -le 65535 ] \
    || die "--discovery-server must be HOST:PORT, e.g. 192.168.1.20:11811"
fi
[ -n "$tables" ] || { [ "$world" = rules ] && [ "$robot" = 0 ] && tables=paper || tables=corrected; }
[[ "$tables" =~ ^(corrected|paper)$ ]] || die "--tables must be corrected or paper"
[[ "$object" =~ ^-?[0-9]+$ ]] || die "--object must be a model index"
[[ "$objects" =~ ^[0-9]+$ ]] && [ "$objects" -ge 1 ] && [ "$objects" -le 20 ] \
  || die "--objects must be an integer from 1 to 20"
[ "$twins" = false ] || [ "$objects" -ge 2 ] || die "--twins needs --objects 2 or more"
[ "$objects" = 1 ] || [ -z "$operator" ] \
  || die "--objects goes with the sim or robot graph: leave out --operator"
tracking_args=(); [ "$objects" -gt 1 ] && tracking_args=(-p multi_object:=true)
[[ "$seed" =~ ^[0-9]+$ ]] || die "--seed must be a non-negative integer"
[ -z "$params" ] || [ -f "$params" ] || die "--params file $params not found"
[ -z "$record" ] || [ ! -e "$record" ] || die "--record $record exists: rosbag2 never overwrites a bag"
if [ -n "$operator" ]; then
  [[ "$operator" =~ ^(person|scripted)$ ]] || die "--operator must be person or scripted"
  [ "$robot" = 0 ] || die "--operator $operator runs without the robot: leave out --robot"
  if [ "$operator" = scripted ]; then
    [ -z "$camera$calibration" ] || die "--operator scripted renders its own camera: leave out --camera and --calibration"
    [[ "${wrong_action_fraction:-0}" =~ ^(0|1|0?[.][0-9]+|1[.]0*)$ ]] || die "--wrong-action-fraction must be a number from 0 to 1"
    wrong_action_fraction="${wrong_action_fraction:-0}"; [[ "$wrong_action_fraction" == *.* ]] || wrong_action_fraction+=".0"
    [[ "$wrong_action_fraction" == .* ]] && wrong_action_fraction="0$wrong_action_fraction"
  else
    [ -n "$camera" ] && [ -n "$calibration" ] || die "--operator person needs --camera and --calibration"
    [ -f "$calibration" ] || die "--calibration file $calibration not found"
    [[ "$camera" =~ ^/dev/ || "$camera" =~ ^[0-9]+$ || -e "$camera" ]] || die "--camera $camera: no such device, file or folder"
  fi
  read -r -a pose_values <<< "$camera_pose"
  [ "${#pose_values[@]}" = 6 ] || die "--camera-pose needs 6 numbers: X Y Z ROLL PITCH YAW"
  pose_param=""   # a YAML list of doubles (a 0 alone would make it a mixed list)
  for v in "${pose_values[@]}"; do
    [[ "$v" =~ ^-?[0-9]+([.][0-9]*)?$ ]] || die "--camera-pose: $v is not a number"
    [[ "$v" == *.* ]] || v="$v."; [[ "$v" == *. ]] && v="${v}0"; pose_param+="${pose_param:+,}$v"
  done
  if [ "$operator" = person ]; then
    calibration="$(cd "$(dirname "$calibration")" && pwd)/$(basename "$calibration")"
    [ -e "$camera" ] && [[ ! "$camera" =~ ^/dev/ ]] && camera="$(cd "$(dirname "$camera")" && pwd)/$(basename "$camera")"
  fi
elif [ -n "$camera$calibration" ]; then
  die "--camera and --calibration go with --operator person"
fi
if [ "$operator" != scripted ] && { [ -n "$wrong_action_fraction" ] || [ "$operator_silent" = true ]; }; then
  die "--wrong-action-fraction and --operator-silent go with --operator scripted"
fi
namespace="${namespace#/}"; namespace="${namespace%/}"
[ -z "$namespace" ] || [[ "$namespace" =~ ^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$ ]] \
  || die "--namespace must be a ROS namespace such as robot1"

# Model-set parameters shared by every node that loads the model set: one `/**:` file.
model_yaml=(seed "$seed" transition_rules "$tables")
# Every node's parameters (/**): the nodes that draw or read tags declare `dictionary`.
[ -n "$dictionary" ] && model_yaml+=(dictionary "$dictionary")
case "$models" in
  robot|full|visual) model_yaml+=(model_set "$models") ;;
  random:*) [[ "${models#random:}" =~ ^[0-9]+$ ]] || die "--models random:N needs a number N"
            model_yaml+=(model_set random model_set_size "${models#random:}") ;;
  *) [ -f "$models" ] || die "--models: $models is neither a set name nor a file"
     file="$(cd "$(dirname "$models")" && pwd)/$(basename "$models")"
     model_yaml+=(model_file "$(yaml_string "$file")") ;;
esac

[ "$build" = 1 ] && "$REPO/scripts/bootstrap.sh"
# shellcheck disable=SC1091
set +u; source "$REPO/scripts/env.sh"; set -u

# SROS2 asked for on a machine whose rmw cannot do it: say so now, not as an rcl error
# in every node's log or as a graph that runs unprotected (docs/OFFBOARD.md).
# Only when security is asked for (rcl reads exactly "true"): a Python start costs time.
[ "${ROS_SECURITY_ENABLE:-}" != true ] || python -m abp_bringup.security_check || exit 2

# The robot profile: checked here (a bad one names its file and key), given to every node
# (/**: the nodes that know the robot declare robot_profile), and its learned model set is
# the default of --models.
if [ -n "$robot_profile" ]; then
  [ -f "$robot_profile" ] || die "--robot-profile: no file $robot_profile"
  robot_profile="$(cd "$(dirname "$robot_profile")" && pwd)/$(basename "$robot_profile")"
  profile_models="$(python -c '
import sys
from abp_description.robot_profile import ProfileError, load_profile
try:
    print(load_profile(sys.argv[1]).models or "")
except ProfileError as error:
    sys.exit(f"[start_graph] error: --robot-profile: {error}")' "$robot_profile")" || exit 2
  model_yaml+=(robot_profile "$(yaml_string "$robot_profile")")
  if [ "$models_given" = 0 ] && [ -n "$profile_models" ]; then
    models="$profile_models"
    model_yaml+=(model_file "$(yaml_string "$models")")
  fi
fi

# The planner modes and the topic names the script needs, from the packages that define them.
planners="$(python -c 'from abp_planner.planner import PLANNER_NAMES; print(*PLANNER_NAMES)')"
[[ " $planners " == *" $planner "* ]] || die "--planner must be one of: $planners"
mapfile -t topics < <(python - "$namespace" <<'PY'
import sys
from abp_common import names
for name in (names.BELIEF, names.ASPECT_OBSERVATION, names.EXECUTED_ACTION, names.PLAN):
    print(names.absolute(name, sys.argv[1]))
PY
)
belief_topic="${topics[0]}"; observation_topic="${topics[1]}"
# The managed nodes this part starts (all of them unless the graph is split, --part).
graph=sim; [ "$robot" = 1 ] && graph=robot; [ -n "$operator" ] && graph=$( [ "$operator" = scripted ] && echo scripted || echo operator)
part_nodes=" $(python -m abp_common.graph_nodes --graph "$graph" --part "$part" --perception "$perception_on" | cut -d' ' -f1 | tr '\n' ' ')"
action_topic="${topics[2]}"; plan_topic="${topics[3]}"

config="$(python -c 'from ament_index_python.packages import get_package_share_directory as g; print(g("abp_bringup"))')/config/abp.yaml"
# A split graph runs over a link that can drop: Fast DDS's participant lease of 5 s instead
# of 20 s (the planner sees a lost link within seconds; docs/OFFBOARD.md), unless the
# environment names its own Fast DDS profile.
if [ "$part" != all ] && [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}${FASTDDS_DEFAULT_PROFILES_FILE:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="${config%/abp.yaml}/fastdds_link.xml"
fi
# Fast DDS 2.14's shared-memory transport does not recover from a subscriber killed while
# large samples flow: the camera's reader, restarted and matched, got no image until the
# publisher restarted (eProsima/Fast-DDS#5469, #5053; docs/RECOVERY.md). The graph's
# processes talk over UDP with socket buffers that hold a camera frame
# (config/fastdds_udp.xml), unless the environment names a Fast DDS profile or other
# transports. With the LOCALHOST discovery range, Jazzy's rmw_fastrtps sets shared memory
# and UDP itself, over any profile's transports: there a profile does the same over UDP on
# the loopback interface only (config/fastdds_loopback_udp.xml), under the SUBNET range,
# which leaves it as it is.
if [ "$part" = all ] && [ -z "${FASTRTPS_DEFAULT_PROFILES_FILE:-}${FASTDDS_DEFAULT_PROFILES_FILE:-}" ] \
    && [ "${FASTDDS_BUILTIN_TRANSPORTS:-UDPv4}" = UDPv4 ]; then
  if [ "${ROS_AUTOMATIC_DISCOVERY_RANGE:-}" = LOCALHOST ] && [ -z "${ROS_STATIC_PEERS:-}" ]; then
    export FASTRTPS_DEFAULT_PROFILES_FILE="${config%/abp.yaml}/fastdds_loopback_udp.xml"
    export ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET
  else
    export FASTRTPS_DEFAULT_PROFILES_FILE="${config%/abp.yaml}/fastdds_udp.xml"
  fi
fi
export FASTDDS_BUILTIN_TRANSPORTS="${FASTDDS_BUILTIN_TRANSPORTS:-UDPv4}"
# A discovery server: every participant (Fast DDS reads ROS_DISCOVERY_SERVER; the position
# in the list is the server's id, 0 here) is its client, so no multicast is needed.
if [ -n "$discovery_server" ]; then
  export ROS_DISCOVERY_SERVER="$discovery_server"
  server_host="${discovery_server%:*}"; server_port="${discovery_server##*:}"
  # This host owns the server when it can bind the server's address.
  server_here="$(python -c '
import socket, sys
try:
    socket.socket(socket.AF_INET, socket.SOCK_DGRAM).bind((socket.gethostbyname(sys.argv[1]), 0))
    print(1)
except OSError:
    print(0)' "$server_host")"
fi
log_dir="${log_dir:-$REPO/log/graph-$(date +%Y%m%d-%H%M%S)}"
mkdir -p "$log_dir"
model_params="$log_dir/model_set.yaml"
{ echo "/**:"; echo "  ros__parameters:"
  for ((i = 0; i < ${#model_yaml[@]}; i += 2)); do
    echo "    ${model_yaml[i]}: ${model_yaml[i+1]}"
  done; } > "$model_params"
ns_args=()
[ -n "$namespace" ] && ns_args=(-r "__ns:=/$namespace")

pids=()
cleanup() {
  # A second Ctrl-C (or a signal to the whole group) must not cut the clean-up short.
  trap - EXIT
  trap '' INT TERM
  # Whoever read our output may be gone (a killed driver): a write to the broken pipe
  # must not kill this shell before it has stopped the nodes.
  trap '' PIPE
  if [ ${#pids[@]} -gt 0 ]; then
    { echo "[start_graph] stopping ${#pids[@]} processes"; } 2>/dev/null || true
    # SIGINT first (the client cancels its goal on it); SIGTERM after 2 s for a process
    # that inherited SIGINT ignored (started in the background of a non-interactive shell).
    kill -INT "${pids[@]}" 2>/dev/null || true
    for tick in $(seq 50); do
      alive=0
      for pid in "${pids[@]}"; do kill -0 "$pid" 2>/dev/null && alive=1; done
      [ "$alive" = 0 ] && break
      [ "$tick" = 20 ] && { kill -TERM "${pids[@]}" 2>/dev/null || true; }
      sleep 0.1
    done
    # A supervisor killed outright would leave its node behind: the nodes go first.
    for pid in "${pids[@]}"; do pkill -KILL -P "$pid" 2>/dev/null || true; done
    kill -KILL "${pids[@]}" 2>/dev/null || true
    wait 2>/dev/null || true
  fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# supervise NAME LOG CMD...: run CMD, appending to LOG; with respawn on, run it again when
# it dies. Exit code 0 (stopped) and 2 (configuration error: a restart cannot fix it) end
# the loop, and so does a third death within 10 s of starting (a crash loop). On
# SIGINT/SIGTERM it passes the signal on to the node and ends with it.
supervise() {
  local name="$1" log="$2"; shift 2
  local child="" stopping=0 quick_deaths=0 restarts=0 rc started
  trap 'stopping=1; [ -n "$child" ] && kill -INT "$child" 2>/dev/null' INT
  trap 'stopping=1; [ -n "$child" ] && kill -TERM "$child" 2>/dev/null' TERM
  while true; do
    started=$SECONDS
    "$@" >> "$log" 2>&1 &
    child=$!
    rc=0
    # `wait` returns early when a trapped signal arrives: wait again for the node itself.
    wait "$child" || rc=$?
    while kill -0 "$child" 2>/dev/null; do wait "$child" || rc=$?; done
    if [ "$stopping" = 1 ] || [ "$respawn" = 0 ] || [ "$rc" = 0 ] || [ "$rc" = 2 ]; then
      exit "$rc"
    fi
    if [ $((SECONDS - started)) -lt 10 ]; then quick_deaths=$((quick_deaths + 1)); else quick_deaths=0; fi
    if [ "$quick_deaths" -ge 3 ]; then
      echo "[start_graph] $name died 3 times within 10 s of starting (exit code $rc): not restarting it; see $log" | tee -a "$log" >&2
      exit "$rc"
    fi
    restarts=$((restarts + 1))
    echo "[start_graph] $name exited with code $rc; restarting it (restart $restarts)" | tee -a "$log" >&2
    sleep 1
    [ "$stopping" = 1 ] && exit "$rc"  # stopped during the pause: no restart
  done
}

# start PACKAGE EXECUTABLE [ros args...]: ros2 run where available, else the installed file.
# The managed nodes (`start_managed`) start unconfigured: the lifecycle manager brings them
# up in the order they were started (and brings a respawned one back).
# With --one-process the managed nodes are not started one by one: their own parameters
# (the -p arguments here, use_sim_time) go to a parameters file under each node's name,
# and one graph_container runs them all (started below).
managed=()   # every managed node of the graph, in bring-up order (the manager's list)
local_managed=()   # those this part starts
container_params="$log_dir/graph_container.yaml"
[ "$one_process" = 1 ] && : > "$container_params"
start_managed() {
  managed+=("$2")
  # Another part's node: the lifecycle manager reaches it over the network.
  [[ "$part_nodes" == *" $2 "* ]] || return 0
  local_managed+=("$2")
  if [ "$one_process" = 0 ]; then
    start "$@" -p autostart:=false
    return
  fi
  local executable="$2" values=""; shift 2
  # The operator graphs run on wall time (no /clock): as start() does for them.
  [ "$robot" = 0 ] && [ "$executable" != sim_bridge ] && values+="    use_sim_time: $( [ -n "$operator" ] && echo false || echo true)"$'\n'
  while [ $# -gt 0 ]; do
    [ "$1" = -p ] || die "start_managed: only -p name:=value arguments (got $1)"
    values+="    ${2%%:=*}: ${2#*:=}"$'\n'; shift 2
  done
  # An empty block would be YAML null, which the parameter parser refuses: write {}.
  { echo "/**/$executable:"
    if [ -n "$values" ]; then echo "  ros__parameters:"; printf '%s' "$values"
    else echo "  ros__parameters: {}"; fi; } >> "$container_params"
}
start() {
  local package="$1" executable="$2"; shift 2
  local sim_time=(-p "use_sim_time:=true")
  [ "$robot" = 1 ] && sim_time=()
  [ -n "$operator" ] && sim_time=()
  [ "$package/$executable" = abp_sim_bridge/sim_bridge ] && sim_time=()
  [ "$package/$executable" = abp_bringup/lifecycle_manager ] && sim_time=()
  local ros_args=(--ros-args --params-file "$config" --params-file "$model_params")
  [ -n "$params" ] && ros_args+=(--params-file "$params")
  ros_args+=("${ns_args[@]}" "${sim_time[@]}" "$@")
  local command=("$REPO/install/$package/lib/$package/$executable")
  command -v ros2 >/dev/null 2>&1 && command=(ros2 run "$package" "$executable")
  : > "$log_dir/$executable.log"
  supervise "$executable" "$log_dir/$executable.log" "${command[@]}" "${ros_args[@]}" &
  pids+=("$!")
}

if [ "${server_here:-0}" = 1 ]; then
  # The PyPI wheels ship fast-discovery-server without the path to their own libraries.
  server_libs="$(python -c '
import glob, os, sys
site = glob.glob(os.path.join(sys.prefix, "lib", "python3*", "site-packages", "ros_fastrtps.libs"))
print(":".join([os.path.join(sys.prefix, "lib"), *site]))')"
  command -v fast-discovery-server >/dev/null 2>&1 || die "--discovery-server: fast-discovery-server is not on PATH (Fast DDS's tools)"
  server_args=(-i 0 -l "$server_host" -p "$server_port")
  # Split: the participant lease of fastdds_link.xml, as every node of the graph.
  [ "$part" = all ] || server_args+=(-x "${config%/abp.yaml}/fastdds_discovery_server.xml")
  : > "$log_dir/discovery_server.log"
  LD_LIBRARY_PATH="$server_libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" \
    supervise discovery_server "$log_dir/discovery_server.log" fast-discovery-server "${server_args[@]}" &
  pids+=("$!")
  echo "[start_graph] discovery server on $discovery_server (server id 0; log $log_dir/discovery_server.log)"
fi
[ -n "$discovery_server" ] && echo "[start_graph] discovery through the server at $discovery_server (ROS_DISCOVERY_SERVER)"
echo "[start_graph] $( [ -n "$operator" ] && echo "operator ($operator)" || { [ "$robot" = 1 ] && echo robot || echo "sim ($world world)"; } ) graph${namespace:+ under /$namespace}$( [ "$part" = all ] || echo ", $part part")${robot_profile:+, robot profile $robot_profile}, models $models$( [ -f "$models" ] || echo " ($tables tables)" ), planner $planner, seed $seed; logs in $log_dir"
if [ -n "$operator" ]; then
  # A camera that does not move and a person for the skills (docs/OPERATOR.md): no sim
  # bridge, no robot_state; the detector takes the camera pose from --camera-pose, not
  # from joint states.
  if [ "$operator" = person ]; then
    echo "[start_graph] operator graph: camera $camera, a person on $operator_terminal"
    loop=false; [ -e "$camera" ] && [[ ! "$camera" =~ ^/dev/ ]] && loop=true
    start_managed abp_perception camera -p "source:=$camera" -p "calibration_file:=$calibration" \
      -p "loop:=$loop"
  else
    # The camera and the person simulated: operator_skills' terminal is the scripted
    # person's pty, linked at operator_pty when its process starts (waited for below).
    operator_terminal="$log_dir/operator_pty"
    rm -f "$operator_terminal"
    echo "[start_graph] scripted operator graph: MuJoCo camera at \"$camera_pose\", wrong actions $wrong_action_fraction$( [ "$operator_silent" = true ] && echo ", SILENT")"
    start_managed abp_sim_bridge scripted_operator -p "terminal_link:=$operator_terminal" \
      -p "model_index:=$object" -p "cube_seed:=$seed" -p "operator_seed:=$seed" \
      -p "camera_pose:=[$pose_param]" -p "wrong_action_fraction:=$wrong_action_fraction" \
      -p "silent:=$operator_silent"
  fi
  start_managed abp_perception artag_detector -p "fixed_camera_pose:=[$pose_param]"
  start_managed abp_perception aspect_matcher
  start_managed abp_belief belief
  start_managed abp_skills operator_skills -p "terminal:=$operator_terminal"
  OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
    start_managed abp_planner planner -p "planner_mode:=$planner" -p "max_actions:=$max_actions"
fi
# The sim or the robot (not indented, so that this block stays as it was).
# Perception on the workstation: JPEG frames cross the link, not raw ones (a mono8 frame of
# the sim is ~300 KB: 10 a second would fill a 20 Mbit/s link).
compressed_args=(); transport_args=()
if [ "$perception_on" = workstation ]; then
  compressed_args=(-p publish_compressed:=true -p "jpeg_quality:=${jpeg_quality:-90}")
  transport_args=(-p image_transport:=compressed)
fi
if [ -z "$operator" ]; then
if [ "$robot" = 0 ]; then
  start_managed abp_sim_bridge sim_bridge -p "world:=$world" -p "model_index:=$object" \
    -p "cube_seed:=$seed" -p "speedup:=$speedup" -p "num_cubes:=$objects" \
    -p "twin_cubes:=$twins" "${compressed_args[@]}"
fi
# The robot's tf tree (/tf, /tf_static, robot_description) from /joint_states and /odom.
start_managed abp_description robot_state
start_managed abp_perception artag_detector "${transport_args[@]}"
start_managed abp_perception aspect_matcher "${tracking_args[@]}"
start_managed abp_belief belief
# The four action servers in one process: four processes, each with its own executor
# taking /joint_states, /odom and /clock, cost about 1.2 cores of the 2 when idle.
start_managed abp_skills skill_servers
# One BLAS thread: the planner's matrix products are small, and a thread pool fighting
# the other nodes for 2 cores made first decisions at |M| = 1470 take up to 430 ms.
OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
  start_managed abp_planner planner -p "planner_mode:=$planner" -p "max_actions:=$max_actions"
fi  # [ -z "$operator" ]
if [ -n "$record" ]; then
  start abp_bringup bag_recorder -p "record_images:=$record_images" -p "output:=$(mkdir -p "$(dirname "$record")" && cd "$(dirname "$record")" && pwd)/$(basename "$record")"
fi

node_list="$(IFS=,; echo "${managed[*]}")"
local_list="$(IFS=,; echo "${local_managed[*]}")"
if [ "$one_process" = 1 ] && [ -n "$local_list" ]; then
  container=("$REPO/install/abp_bringup/lib/abp_bringup/graph_container")
  command -v ros2 >/dev/null 2>&1 && container=(ros2 run abp_bringup graph_container)
  container+=(--nodes "$local_list" --ros-args --params-file "$config" --params-file "$model_params")
  [ -n "$params" ] && container+=(--params-file "$params")
  container+=("${ns_args[@]}" --params-file "$container_params" -p autostart:=false)
  : > "$log_dir/graph_container.log"
  # One BLAS thread, as for the planner in its own process (above).
  OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
    supervise graph_container "$log_dir/graph_container.log" "${container[@]}" &
  pids+=("$!")
fi
if [ "$operator" = scripted ]; then
  # operator_skills opens its terminal when the manager configures it.
  for _ in $(seq 600); do [ -L "$operator_terminal" ] && break; sleep 0.1; done
  [ -L "$operator_terminal" ] || { echo "[start_graph] the scripted operator made no pty at $operator_terminal within 60 s; its log:" >&2; tail -5 "$log_dir/$( [ "$one_process" = 1 ] && echo graph_container || echo scripted_operator).log" >&2; exit 1; }
fi
if [ "$part" = robot ]; then
  # The workstation's lifecycle manager brings these nodes up over the network.
  echo "[start_graph] robot part up: ${local_managed[*]} started unconfigured, for the" \
       "workstation's lifecycle manager; serving until Ctrl-C"
  wait || true
  exit 0
fi
start abp_bringup lifecycle_manager -p "node_names:=[$node_list]"
manager_log="$log_dir/lifecycle_manager.log"

# Wait for the manager's `graph ready`. A node that fails at start-up (a bad parameter or
# a missing model file: configure refused; or a process that exits) ends the run with
# its log shown.
show_error_logs() {
  for log in "$log_dir"/*.log; do
    grep -qi "error\|failed" "$log" 2>/dev/null && { echo "== $log" >&2; tail -5 "$log" >&2; }
  done
}
started_at=$SECONDS
until grep -q "graph ready" "$manager_log" 2>/dev/null; do
  if grep -q "bringup failed" "$manager_log" 2>/dev/null; then
    echo "[start_graph] a node failed to start; its log:" >&2
    show_error_logs
    exit 1
  fi
  for i in "${!pids[@]}"; do
    if ! kill -0 "${pids[$i]}" 2>/dev/null; then
      echo "[start_graph] a node exited at start-up; its log:" >&2
      show_error_logs
      exit 1
    fi
  done
  if [ $((SECONDS - started_at)) -ge 600 ]; then
    echo "[start_graph] the graph is not ready after 600 s: $(grep "waiting:" "$manager_log" | tail -1)" >&2
    exit 1
  fi
  sleep 0.2
done
echo "[start_graph] graph ready: ${managed[*]} active"

if [ -n "$record" ]; then
  # Subscriptions match their publishers some time after a node starts: wait until the
  # recorder hears the belief and the observations, so the bag has the episode's start,
  # and has matched the planner's publishers of the actions and plans, which are volatile
  # (a message sent before the match is not in the bag).
  wanted=("first message on $belief_topic" "publisher matched on $action_topic"
          "publisher matched on $plan_topic")
  [ "$robot" = 0 ] && wanted+=("first message on $observation_topic")
  for line in "${wanted[@]}"; do
    for _ in $(seq 300); do
      grep -qF "$line" "$log_dir/bag_recorder.log" 2>/dev/null && break
      sleep 0.1
    done
    grep -qF "$line" "$log_dir/bag_recorder.log" 2>/dev/null \
      || echo "[start_graph] warning: the recorder has not logged '$line' after 30 s" >&2
  done
fi

if [ "$serve" = 1 ]; then
  echo "[start_graph] graph up: serving until Ctrl-C (no goal sent)"
  # `wait` returns at once when a trapped signal arrives, so Ctrl-C still stops the graph.
  wait || true
  exit 0
fi

client_args=(--planner "$planner" --max-actions "$max_actions" --timeout "$timeout")
[ -n "$result_json" ] && client_args+=(--result-json "$result_json")
[ -n "$namespace" ] && client_args+=(--ros-args "${ns_args[@]}")
# In the background with `wait`, so that a SIGINT/SIGTERM sent to this script runs
# its trap at once (bash defers traps while a foreground child runs).
"$REPO/install/abp_bringup/lib/abp_bringup/recognize" "${client_args[@]}" &
pids+=("$!")
rc=0
wait "$!" || rc=$?
exit "$rc"
