# Source this file to get the workspace environment (the venv, the ROS 2 Jazzy wheels and the
# colcon install space). Every command of the project runs under it.
_VM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# colcon's setup.bash does not put the venv (the underlay holding the ROS wheels) on
# AMENT_PREFIX_PATH, so export it before sourcing the install space.
export AMENT_PREFIX_PATH="$_VM_ROOT/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export CMAKE_PREFIX_PATH="$_VM_ROOT/.venv${CMAKE_PREFIX_PATH:+:$CMAKE_PREFIX_PATH}"
# The activate and colcon scripts read unset variables: relax `set -u` while sourcing them.
case $- in *u*) _VM_NOUNSET=1; set +u ;; *) _VM_NOUNSET= ;; esac
# shellcheck disable=SC1091
source "$_VM_ROOT/.venv/bin/activate"
# shellcheck disable=SC1091
source "$_VM_ROOT/install/setup.bash"
[ -n "$_VM_NOUNSET" ] && set -u
# Run graphs on this host only, so parallel runs and other machines do not hear each other.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# The estimators work on many small matrices: BLAS threads only add contention on them (a 6x6
# matrix exponential took 20 ms with 2 OpenBLAS threads vs 85 us with one on a loaded machine).
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
export RCUTILS_COLORIZED_OUTPUT="${RCUTILS_COLORIZED_OUTPUT:-0}"
unset _VM_ROOT _VM_NOUNSET
