# shellcheck shell=bash
# Set up (once) and enter the seaforce_ros environment. Source it: `source scripts/setup.sh`.
#
# 1. a virtual environment in .venv with the pinned ROS 2 Jazzy wheels and Python deps
#    (the venv prefix plays the role of /opt/ros/jazzy),
# 2. the CMake-path repair those wheels need (scripts/fix_cmake_paths.py, idempotent),
# 3. colcon build of msg_defs/ (seaforce_msgs) and this package into install/, with
#    compat/control_msgs (the gripper actions' interfaces) only when the distribution's
#    control_msgs cannot be imported (compat/README.md: on a ROS machine it never is built),
# 4. the environment: install/setup.bash, localhost-only discovery, a ROS_DOMAIN_ID, BLAS on
#    one thread.
# Each step is skipped when a stamp of its inputs says nothing changed, so a second run takes
# a few seconds. SEAFORCE_PYTHON selects the interpreter (default python3.11, else python3).

_sf_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_sf_venv="$_sf_root/.venv"
_sf_log() { printf '[setup] %s\n' "$*" >&2; }
_sf_hash() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

_sf_setup() {
  local py="${SEAFORCE_PYTHON:-}"
  if [ -z "$py" ]; then
    if command -v python3.11 >/dev/null 2>&1; then py=python3.11; else py=python3; fi
  fi
  if ! "$py" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
    _sf_log "ROS 2 Jazzy wheels on PyPI are built for CPython 3.11; $py is $("$py" --version 2>&1)."
    _sf_log "Install Python 3.11 or set SEAFORCE_PYTHON to a 3.11 interpreter."
    return 1
  fi
  for tool in cmake gcc g++; do
    command -v "$tool" >/dev/null 2>&1 || { _sf_log "$tool is required to build the message package (apt-get install cmake g++)"; return 1; }
  done

  # 1. virtual environment and pinned packages
  # the interpreter in the stamp is the venv's once there is one (the one pip installs
  # into): a shell whose python3.11 is another build (pyenv beside /usr/bin) must not
  # reinstall the same packages each time it alternates with the other
  local req_stamp stamp_py="$py"
  [ -x "$_sf_venv/bin/python" ] && stamp_py="$_sf_venv/bin/python"
  req_stamp="$(_sf_hash "$_sf_root/scripts/requirements.txt" "$_sf_root/scripts/constraints.txt" "$_sf_root/scripts/fix_cmake_paths.py")-$("$stamp_py" -VV 2>/dev/null | sha256sum | cut -c1-8)"
  if [ ! -x "$_sf_venv/bin/python" ] || [ "$(cat "$_sf_venv/.seaforce-req" 2>/dev/null)" != "$req_stamp" ]; then
    local t0=$SECONDS
    [ -x "$_sf_venv/bin/python" ] || { _sf_log "creating virtual environment $_sf_venv"; "$py" -m venv "$_sf_venv" || return 1; }
    _sf_log "installing pinned ROS 2 Jazzy wheels and Python dependencies (about a minute the first time)"
    # pip's output goes to a log; shown (without the harmless "find-links location is
    # ignored" lines some machines' pip configuration produces by the hundred) on failure
    mkdir -p "$_sf_root/log"
    local pip_log="$_sf_root/log/seaforce-pip.txt" pip_noise='is ignored: it is neither a file nor a directory'
    if ! "$_sf_venv/bin/python" -m pip install --quiet --disable-pip-version-check \
        -r "$_sf_root/scripts/requirements.txt" -c "$_sf_root/scripts/constraints.txt" \
        > "$pip_log" 2>&1; then
      grep -v -e "$pip_noise" "$pip_log" | tail -40 >&2
      _sf_log "pip install failed; full output in $pip_log"
      return 1
    fi
    grep -v -e "$pip_noise" "$pip_log" >&2 || true
    # 2. CMake-path repair (idempotent)
    "$_sf_venv/bin/python" "$_sf_root/scripts/fix_cmake_paths.py" "$_sf_venv" || return 1
    echo "$req_stamp" > "$_sf_venv/.seaforce-req"
    _sf_log "environment ready in $((SECONDS - t0)) s"
  fi

  # 3. colcon build, when an input of the build changed. Python modules are symlinked
  # (--symlink-install), so editing them needs no rebuild; adding or removing one does.
  # control_msgs: from the underlay when it has one (a ROS machine's /opt/ros), else the
  # stand-in compat/control_msgs, named by an explicit path (compat/COLCON_IGNORE keeps it out
  # of every crawl); asked without this workspace's install/ on the path
  local compat=() underlay_path
  underlay_path="$(printf '%s' "${PYTHONPATH:-}" | tr ':' '\n' | grep -v -F "$_sf_root/install" | paste -sd:)"
  if ! PYTHONPATH="$underlay_path" "$_sf_venv/bin/python" -c 'import control_msgs.action' 2>/dev/null; then
    compat=(--paths compat/control_msgs)
  elif [ -d "$_sf_root/install/control_msgs" ]; then
    rm -rf "$_sf_root/install/control_msgs" "$_sf_root/build/control_msgs"   # the underlay's now
  fi
  local build_stamp
  build_stamp="$( (cat "$_sf_venv/.seaforce-req"; echo "compat: ${compat[*]}"; cd "$_sf_root" && find msg_defs config launch resource package.xml setup.py setup.cfg ${compat[@]:+compat} -type f -print0 | sort -z | xargs -0 sha256sum; find seaforce_ros -name '*.py' | sort) | sha256sum | cut -c1-16)"
  if [ ! -f "$_sf_root/install/setup.bash" ] || [ "$(cat "$_sf_root/install/.seaforce-build" 2>/dev/null)" != "$build_stamp" ]; then
    local t0=$SECONDS
    _sf_log "building seaforce_msgs${compat[*]:+, control_msgs (compat)} and seaforce_ros with colcon"
    ( cd "$_sf_root" \
      && export PATH="$_sf_venv/bin:$PATH" AMENT_PREFIX_PATH="$_sf_venv" CMAKE_PREFIX_PATH="$_sf_venv" \
      && "$_sf_venv/bin/colcon" --log-base log build --base-paths . msg_defs ${compat[@]+"${compat[@]}"} --symlink-install \
           --event-handlers console_cohesion- summary- status- \
           --cmake-args -DPython3_EXECUTABLE="$_sf_venv/bin/python" -DBUILD_TESTING=OFF \
           > "$_sf_root/log/seaforce-build.txt" 2>&1 ) \
      || { _sf_log "colcon build failed; see log/seaforce-build.txt:"; tail -30 "$_sf_root/log/seaforce-build.txt" >&2; return 1; }
    echo "$build_stamp" > "$_sf_root/install/.seaforce-build"
    _sf_log "build done in $((SECONDS - t0)) s"
  fi
}

mkdir -p "$_sf_root/log"
if _sf_setup; then
  # 4. environment
  export PATH="$_sf_venv/bin:$PATH" AMENT_PREFIX_PATH="$_sf_venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
  # shellcheck disable=SC1091
  case $- in *u*) set +u; source "$_sf_root/install/setup.bash"; set -u ;; *) source "$_sf_root/install/setup.bash" ;; esac
  export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
  export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}"
  export SEAFORCE_ROOT="$_sf_root"
  # numpy/scipy's BLAS on one thread: the project's matrices are a few rows wide, and on a
  # busy 2-core host BLAS's threads spend their time waiting for each other (the commissioning
  # prediction took 7 s instead of 1.3 s beside the tests' nodes)
  export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
  _sf_ok=0
else
  _sf_ok=1
fi
unset -f _sf_setup _sf_log _sf_hash
[ "$_sf_ok" = 0 ]
