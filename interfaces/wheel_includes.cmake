# Included by each package under interfaces/ (after its find_package calls).
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)

# The ROS wheels from PyPI export CMake targets whose include paths point at
# the machine that built the wheels (/opt/python/...). Point them at this
# machine's Python and NumPy instead, or configure fails with
# "includes non-existent path".
function(al5d_fix_wheel_includes)
  get_property(_dirs DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(_t IN LISTS _dirs)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc AND "${_inc}" MATCHES "/opt/python/")
      set(_new "")
      foreach(_d IN LISTS _inc)
        if("${_d}" MATCHES "/opt/python/")
          if("${_d}" MATCHES "numpy")
            list(APPEND _new ${Python3_NumPy_INCLUDE_DIRS})
          else()
            list(APPEND _new ${Python3_INCLUDE_DIRS})
          endif()
        else()
          list(APPEND _new "${_d}")
        endif()
      endforeach()
      list(REMOVE_DUPLICATES _new)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
    endif()
  endforeach()
endfunction()

# The Makefile builds these packages into the venv, where their only users are Python (the
# server, its clients, the tests): with -DAL5D_PYTHON_ONLY=ON the C++ generators are left
# out, which were 40 % of the build's CPU time (control_msgs: 63 -> 38 CPU s on 2 cores).
# The generators register themselves when the message packages we depend on are found, so
# they are taken off the list the interface generation runs. A colcon build keeps them all.
option(AL5D_PYTHON_ONLY "Generate the C and Python interfaces only" OFF)
if(AL5D_PYTHON_ONLY)
  list(FILTER AMENT_EXTENSIONS_rosidl_generate_idl_interfaces EXCLUDE REGEX "_cpp:")
endif()
