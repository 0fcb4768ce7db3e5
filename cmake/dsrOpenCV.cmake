# Debian's split OpenCV dev packages (core/imgproc) ship no CMake config: make
# opencv::core and opencv::imgproc imported targets from the installed
# headers and libraries. Used by the build and by the installed dsrConfig.cmake (io/ links
# them privately, so a consumer of the static dsr::io needs the same targets).
find_path(OPENCV_INCLUDE_DIR opencv2/core.hpp PATH_SUFFIXES opencv4 REQUIRED)
foreach(m core imgproc)
  if(NOT TARGET opencv::${m})
    find_library(OPENCV_${m}_LIBRARY opencv_${m} REQUIRED)
    add_library(opencv::${m} UNKNOWN IMPORTED)
    set_target_properties(opencv::${m} PROPERTIES IMPORTED_LOCATION "${OPENCV_${m}_LIBRARY}"
                          INTERFACE_INCLUDE_DIRECTORIES "${OPENCV_INCLUDE_DIR}")
  endif()
endforeach()
