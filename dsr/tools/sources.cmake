# The sources of the tools' shared libraries, relative to tools/: tools/CMakeLists.txt builds
# them for the command-line programs, python/CMakeLists.txt for the Python module when it
# links an installed dsr (they are front-end code, not installed).
set(DSR_TOOL_UTIL_SOURCES tool_util.cc output_plan.cc)
set(DSR_TOOL_FLAGS_SOURCES flags/defaults.cc flags/field_of_view.cc flags/frames.cc flags/mask.cc
    flags/mode.cc flags/panorama.cc flags/registration.cc flags/simulation.cc)
