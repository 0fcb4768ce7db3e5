# Smoke test of one flagfile of configs/ (tests/CMakeLists.txt adds one test per file, named
# after it): runs the file's tool with --flagfile=FILE on a tiny simulated sequence, with
# flags after the flagfile that shrink the work (a later flag overrides the file's): 3
# frames of 20x20x16 voxels, one pyramid level, 2 iterations. It runs in a fresh folder
# (WORK_DIR) as the documented workflow runs from the repository root: the folder of every
# path the flagfile names exists, and its relative outputs land in WORK_DIR. Fails when
# the tool refuses the flagfile or the run fails.
#   cmake -DTOOL_NAME=dsr_register -DTOOL=<binary> -DSIMULATE=<dsr_simulate binary>
#         -DFLAGFILE=<file> -DWORK_DIR=<folder> -P run_config_smoke.cmake
foreach(variable TOOL_NAME TOOL SIMULATE FLAGFILE WORK_DIR)
  if(NOT DEFINED ${variable})
    message(FATAL_ERROR "run_config_smoke.cmake: -D${variable}=... is missing")
  endif()
endforeach()
file(REMOVE_RECURSE ${WORK_DIR})
file(MAKE_DIRECTORY ${WORK_DIR})

# The folders of the paths the flagfile names (relative to the repository root; an absolute
# path would let the test write outside its folder).
file(STRINGS ${FLAGFILE} lines)
foreach(line IN LISTS lines)
  if(line MATCHES "^--[A-Za-z0-9_]+=(.+)$")
    string(REPLACE "," ";" values "${CMAKE_MATCH_1}")
    foreach(value IN LISTS values)
      if(IS_ABSOLUTE "${value}")
        message(FATAL_ERROR "${FLAGFILE}: ${line}: paths in configs/ are relative to the "
                            "repository root")
      endif()
      if(value MATCHES "/")
        get_filename_component(folder "${value}" DIRECTORY)
        file(MAKE_DIRECTORY ${WORK_DIR}/${folder})
      endif()
    endforeach()
  endif()
endforeach()

# Runs `command` in WORK_DIR; stops the test with its output unless it exits 0.
function(run what)
  execute_process(COMMAND ${ARGN} WORKING_DIRECTORY ${WORK_DIR} RESULT_VARIABLE status
                  OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT status EQUAL 0)
    string(REPLACE ";" " " command "${ARGN}")
    message(FATAL_ERROR "${what} failed (exit status ${status}):\n${command}\n"
                        "--- stdout\n${out}--- stderr\n${err}")
  endif()
endfunction()

set(tiny --phantom_size=48 --frame_size=20,20,16 --num_frames=3 --max_rotation_deg=4
         --max_translation_voxels=1 --min_depth_voxels=2)
set(short --pyramid_levels=1 --max_iterations=2 --progress=false)
set(input smoke_input)
set(images ${input}/frame_00.nii.gz,${input}/frame_01.nii.gz,${input}/frame_02.nii.gz)
set(masks ${input}/mask_00.nii.gz,${input}/mask_01.nii.gz,${input}/mask_02.nii.gz)

if(TOOL_NAME STREQUAL "dsr_simulate")
  run("${FLAGFILE}" ${TOOL} --flagfile=${FLAGFILE} ${tiny})
elseif(TOOL_NAME STREQUAL "dsr_compare")
  run("${FLAGFILE}" ${TOOL} --flagfile=${FLAGFILE} --num_sequences=1 ${tiny} ${short})
elseif(TOOL_NAME STREQUAL "dsr_register" OR TOOL_NAME STREQUAL "dsr_fuse")
  run("the tiny input sequence" ${SIMULATE} --out_dir=${input} ${tiny} --sigma=5)
  if(TOOL_NAME STREQUAL "dsr_register")
    run("${FLAGFILE}" ${TOOL} --flagfile=${FLAGFILE} --images=${images} --masks=${masks}
        --gt_poses=${input}/gt_poses.json ${short})
  else()
    run("${FLAGFILE}" ${TOOL} --flagfile=${FLAGFILE} --images=${images} --masks=${masks}
        --poses=${input}/gt_poses.json)
  endif()
else()
  message(FATAL_ERROR "${FLAGFILE}: no smoke run for ${TOOL_NAME} (tests/run_config_smoke.cmake)")
endif()
file(REMOVE_RECURSE ${WORK_DIR})
