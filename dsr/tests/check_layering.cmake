# The Layering.IncludesFollowTheLibraryLinks test: every #include "dsr/<folder>/..." in a
# library folder names its own folder or one its library links (directly or not), so the
# dependencies between folders go one way and match the CMake targets. The folders' tests
# (*_test.cc and their *_test_* helpers) are left out: a test may use layers above the one
# it tests (simulated data, the pipeline), and its links are its own.
# cmake -DSOURCE_DIR=... -DLAYERS=<file of "folder: allowed,folders" lines> -P this
cmake_policy(SET CMP0057 NEW)  # if(... IN_LIST ...)
file(STRINGS ${LAYERS} lines)
set(violations "")
foreach(line ${lines})
  string(REGEX REPLACE ":.*" "" folder "${line}")
  string(REGEX REPLACE "^[^:]*: *" "" allowed "${line}")
  string(REPLACE "," ";" allowed "${allowed}")
  file(GLOB_RECURSE sources ${SOURCE_DIR}/${folder}/*.h ${SOURCE_DIR}/${folder}/*.cc
       ${SOURCE_DIR}/${folder}/*.inc)
  list(FILTER sources EXCLUDE REGEX "_test(_[a-z_]+)?\\.(cc|h)$")
  foreach(source ${sources})
    file(STRINGS ${source} includes REGEX "^#include \"dsr/")
    foreach(include ${includes})
      string(REGEX REPLACE "^#include \"dsr/([a-z_]+)/.*" "\\1" used "${include}")
      if(NOT used STREQUAL folder AND NOT used IN_LIST allowed)
        file(RELATIVE_PATH name ${SOURCE_DIR} ${source})
        list(APPEND violations "${name}: ${include} (${folder}/ links only: ${allowed})")
      endif()
    endforeach()
  endforeach()
endforeach()
if(violations)
  string(REPLACE ";" "\n" violations "${violations}")
  message(FATAL_ERROR "includes against the library links:\n${violations}")
endif()
