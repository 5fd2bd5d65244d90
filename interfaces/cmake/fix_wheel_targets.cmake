# Injected with -DCMAKE_PROJECT_INCLUDE=... (upstream CMakeLists.txt stay untouched).
# The ros-* PyPI wheels were built in a manylinux container; their exported
# <pkg>__rosidl_generator_py targets carry that container's absolute include
# dirs (/opt/python/cp311-cp311/...), which do not exist here. At the end of the
# top-level directory (after all find_package calls), rewrite them to this
# interpreter's Python and NumPy include dirs.
function(_fix_ros_wheel_imported_targets)
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  get_directory_property(_targets IMPORTED_TARGETS)
  foreach(_t IN LISTS _targets)
    get_target_property(_inc ${_t} INTERFACE_INCLUDE_DIRECTORIES)
    if(_inc AND "${_inc}" MATCHES "/opt/python/")
      set(_new)
      foreach(_d IN LISTS _inc)
        if(_d MATCHES "^/opt/python/.*/numpy/")
          list(APPEND _new ${Python3_NumPy_INCLUDE_DIRS})
        elseif(_d MATCHES "^/opt/python/")
          list(APPEND _new ${Python3_INCLUDE_DIRS})
        else()
          list(APPEND _new "${_d}")
        endif()
      endforeach()
      list(REMOVE_DUPLICATES _new)
      set_target_properties(${_t} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_new}")
      message(STATUS "fix_wheel_targets: ${_t} -> ${_new}")
    endif()
  endforeach()
endfunction()
if(CMAKE_CURRENT_SOURCE_DIR STREQUAL CMAKE_SOURCE_DIR)
  cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _fix_ros_wheel_imported_targets)
endif()
