#!/usr/bin/env bash
# Set up the project-local environment `.venv` for clutch_ros, idempotently.
#
# Steps (each skipped when its inputs have not changed since the last successful run):
#   1. check prerequisites: CPython 3.11 (the ROS 2 wheels on the package index are cp311),
#      cmake and a C compiler;
#   2. create .venv and install the pinned requirements.txt (ROS 2 wheels, python-can,
#      cantools, numpy, scipy, rosbags, pytest, ...);
#   3. rewrite the build machine's Python include dirs baked into the ROS message wheels'
#      exported CMake targets to this machine's (see README.md, "Set up and go");
#   4. build and install the interface package msg_defs/ (clutch_msgs) into .venv;
#   5. make `clutch_ros` importable from the source tree (editable, via a .pth file) and put
#      the `clutch` command into .venv/bin.
#
# Usage: tools/bootstrap.sh [--quiet]
# Environment: CLUTCH_PYTHON=/path/to/python3.11 to choose the interpreter.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
stamps="$venv/.stamps"
quiet=0
[ "${1:-}" = "--quiet" ] && quiet=1

say() { [ "$quiet" = 1 ] || echo "bootstrap: $*" >&2; }
die() { echo "bootstrap: error: $*" >&2; exit 1; }

hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -d' ' -f1; }

# --- 1. prerequisites -------------------------------------------------------------------
find_python() {
    local cand
    for cand in "${CLUTCH_PYTHON:-}" python3.11 python3; do
        [ -n "$cand" ] || continue
        command -v "$cand" >/dev/null 2>&1 || continue
        if "$cand" -c 'import sys, venv; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' 2>/dev/null; then
            command -v "$cand"
            return 0
        fi
    done
    return 1
}

if [ ! -x "$venv/bin/python" ]; then
    py="$(find_python)" || die "CPython 3.11 with the venv module is required (the ROS 2 wheels on the package index are built for cp311); install python3.11 or set CLUTCH_PYTHON"
fi
command -v cmake >/dev/null 2>&1 || die "cmake is required to build msg_defs (apt-get install cmake)"
command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1 || die "a C compiler (cc/gcc) is required to build msg_defs (apt-get install gcc g++)"
command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || die "a C++ compiler (c++/g++) is required to build msg_defs (apt-get install g++)"

# --- 2. virtual environment and pinned packages ----------------------------------------
if [ ! -x "$venv/bin/python" ]; then
    say "creating $venv with $py"
    "$py" -m venv "$venv" || die "could not create the virtual environment $venv"
fi
mkdir -p "$stamps"
vpy="$venv/bin/python"

req_hash="$(hash_of "$root/requirements.txt")"
if [ "$(cat "$stamps/requirements" 2>/dev/null)" != "$req_hash" ]; then
    say "installing pinned requirements (first run takes about a minute)"
    mkdir -p "$venv/build"
    if ! "$vpy" -m pip install --disable-pip-version-check -q -r "$root/requirements.txt" \
            > "$venv/build/pip.log" 2>&1; then
        grep -v "is ignored: it is neither a file nor a directory" "$venv/build/pip.log" \
            | tail -n 20 >&2
        die "pip could not install requirements.txt (is the package index reachable?); log: $venv/build/pip.log"
    fi
    rm -f "$stamps/cmake_paths" "$stamps/msg_defs"
    echo "$req_hash" > "$stamps/requirements"
fi

# --- 3. CMake include-path rewrite -------------------------------------------------------
if [ ! -f "$stamps/cmake_paths" ]; then
    say "rewriting Python include dirs in the ROS wheels' CMake exports"
    "$vpy" - "$venv" <<'PY'
import glob, re, sys, sysconfig
import numpy
venv = sys.argv[1]
py_inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
pat_py = re.compile(r"/opt/python/cp\d+-cp\d+/include/python3\.\d+")
pat_np = re.compile(r"/opt/python/cp\d+-cp\d+/lib/python3\.\d+/site-packages/numpy/_core/include")
for path in glob.glob(f"{venv}/share/*/cmake/*.cmake"):
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    new = pat_py.sub(py_inc, pat_np.sub(np_inc, text))
    if new != text:
        with open(path, "w", encoding="utf-8") as fh:
            fh.write(new)
PY
    touch "$stamps/cmake_paths"
fi

# --- 4. msg_defs -> .venv ------------------------------------------------------------------
msg_hash="$(cd "$root" && find msg_defs -type f | LC_ALL=C sort | xargs cat | sha256sum | cut -d' ' -f1)"
if [ "$(cat "$stamps/msg_defs" 2>/dev/null)" != "$msg_hash" ] \
   || ! "$vpy" -c 'import clutch_msgs.msg' >/dev/null 2>&1; then
    say "building msg_defs (clutch_msgs) into .venv"
    build="$venv/build/msg_defs"
    rm -rf "$build"
    log="$venv/build/msg_defs.log"
    mkdir -p "$build"
    if ! (cmake -S "$root/msg_defs" -B "$build" -DCMAKE_PREFIX_PATH="$venv" \
            -DCMAKE_INSTALL_PREFIX="$venv" -DPython3_EXECUTABLE="$vpy" -DBUILD_TESTING=OFF \
          && cmake --build "$build" -j"$(nproc)" && cmake --install "$build") > "$log" 2>&1; then
        tail -n 30 "$log" >&2
        die "building msg_defs failed; full log: $log"
    fi
    "$vpy" -c 'import clutch_msgs.msg' || die "clutch_msgs built but does not import"
    echo "$msg_hash" > "$stamps/msg_defs"
fi

# --- 5. clutch_ros itself (editable) -----------------------------------------------------
site="$("$vpy" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
echo "$root" > "$site/clutch_ros_src.pth"
cat > "$venv/bin/clutch" <<EOF
#!/usr/bin/env bash
exec "$vpy" -m clutch_ros.cli "\$@"
EOF
chmod +x "$venv/bin/clutch"

# --- 6. compiled code into numba's cache (a can_bridge's first configure then loads it) ----
"$vpy" -c 'import sys; from clutch_ros.canbus.udp_columns import warm_up; r = warm_up(); r and print(f"note: the can_bridge decodes in Python: {r}", file=sys.stderr)' \
    || die "warming the compiled CAN intake failed"
say "environment ready: $venv"
