# >>> al5d (make install, ros/venv/activate.sh): the venv is an ament prefix
# colcon and ament find ROS 2's packages in it through AMENT_PREFIX_PATH, as in a sourced
# ROS install (docs/moveit.md, without a ROS install); deactivate takes it back out.
if [ -z "${_AL5D_AMENT_ACTIVE:-}" ]; then
    _AL5D_AMENT_ACTIVE=1
    _AL5D_OLD_AMENT_PREFIX_PATH="${AMENT_PREFIX_PATH:-}"
    . "$VIRTUAL_ENV/local_setup.sh"
    # The venv's own deactivate, kept under another name and called by ours.
    eval "_al5d_venv_$(typeset -f deactivate)"
    deactivate () {
        if [ -n "$_AL5D_OLD_AMENT_PREFIX_PATH" ]; then
            AMENT_PREFIX_PATH="$_AL5D_OLD_AMENT_PREFIX_PATH"
            export AMENT_PREFIX_PATH
        else
            unset AMENT_PREFIX_PATH
        fi
        unset _AL5D_AMENT_ACTIVE _AL5D_OLD_AMENT_PREFIX_PATH
        _al5d_venv_deactivate "$@"
        if [ "${1:-}" != nondestructive ]; then
            unset -f _al5d_venv_deactivate
        fi
    }
fi
# <<< al5d
