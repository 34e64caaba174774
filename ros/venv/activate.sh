# >>> al5d (make install, ros/venv/activate.sh): the venv is an ament prefix
# colcon and ament find ROS 2's packages in it through AMENT_PREFIX_PATH, as in a sourced
# ROS install (docs/moveit.md, without a ROS install); deactivate takes it back out.
_al5d_ament_restore () {
    if [ -n "${_AL5D_OLD_AMENT_PREFIX_PATH:-}" ]; then
        AMENT_PREFIX_PATH="$_AL5D_OLD_AMENT_PREFIX_PATH"
        export AMENT_PREFIX_PATH
    else
        unset AMENT_PREFIX_PATH
    fi
    unset _AL5D_AMENT_ACTIVE _AL5D_OLD_AMENT_PREFIX_PATH
}
# Activated again: the venv's activate has put its own deactivate back before it ran it.
if [ -n "${_AL5D_AMENT_ACTIVE:-}" ]; then
    _al5d_ament_restore
fi
_AL5D_AMENT_ACTIVE=1
_AL5D_OLD_AMENT_PREFIX_PATH="${AMENT_PREFIX_PATH:-}"
. "$VIRTUAL_ENV/local_setup.sh"
# The venv's own deactivate, kept under another name and called by ours (bash and zsh,
# the shells bin/activate is for: a POSIX sh, which the Makefile's builds source it in,
# has no typeset, and no deactivate of ours then).
if command -v typeset > /dev/null 2>&1; then
    eval "_al5d_venv_$(typeset -f deactivate)"
    deactivate () {
        _al5d_ament_restore
        _al5d_venv_deactivate "$@"
        if [ "${1:-}" != nondestructive ]; then
            unset -f _al5d_venv_deactivate _al5d_ament_restore
        fi
    }
fi
# <<< al5d
