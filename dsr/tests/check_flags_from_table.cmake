# The Flags.ComeFromTheOptionsTable test: no gflags flag is defined in the tools or the
# Python module: every option is declared once, in the options table (dsr/app/options.cc),
# from which the tools register their flags, Python takes its keyword arguments and the
# docs' option reference is made. The tests (*_test.cc) are left out.
# cmake -DSOURCE_DIR=<repository root> -P this
file(GLOB_RECURSE sources ${SOURCE_DIR}/dsr/tools/*.cc ${SOURCE_DIR}/dsr/app/*.cc
     ${SOURCE_DIR}/python/src/*.cc)
list(FILTER sources EXCLUDE REGEX "_test\\.cc$")
set(found "")
foreach(source ${sources})
  file(RELATIVE_PATH name ${SOURCE_DIR} ${source})
  file(STRINGS ${source} definitions REGEX "^ *DEFINE_(bool|int32|int64|uint64|double|string|validator)\\(")
  foreach(definition ${definitions})
    list(APPEND found "${name}: ${definition}")
  endforeach()
endforeach()
list(LENGTH sources count)
if(count LESS 5)
  message(FATAL_ERROR "found only ${count} sources under ${SOURCE_DIR}/dsr/tools and dsr/app")
endif()
if(found)
  string(REPLACE ";" "\n" found "${found}")
  message(FATAL_ERROR "flags defined outside the options table (dsr/app/options.cc):\n${found}")
endif()
