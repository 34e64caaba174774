# This venv as an ament prefix, as a ROS install's own local_setup.sh makes it one: ament
# and colcon find the packages in it (ROS 2's wheels, the messages `make install` builds)
# through AMENT_PREFIX_PATH. Written by al5d's `make install` (ros/venv/local_setup.sh);
# sourced by the venv's bin/activate and by the install/setup.* of a colcon workspace
# built against the venv (colcon chains every prefix that has a local_setup script).
_al5d_prefix="@PREFIX@"
case ":${AMENT_PREFIX_PATH:-}:" in
    *":$_al5d_prefix:"*) ;;
    *)
        AMENT_PREFIX_PATH="$_al5d_prefix${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
        export AMENT_PREFIX_PATH
        ;;
esac
unset _al5d_prefix
