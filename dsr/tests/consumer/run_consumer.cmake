# The Consumer.FindPackageBuildsAndRegisters test: installs the build tree into a fresh
# prefix, configures and builds tests/consumer against it with find_package(dsr), and runs
# the program. cmake -DBUILD_DIR=... -DSOURCE_DIR=... -DWORK_DIR=... -DGENERATOR=... -P this
file(REMOVE_RECURSE ${WORK_DIR})
function(run_step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE status OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT status EQUAL 0)
    message(FATAL_ERROR "consumer test: ${what} failed (${status}):\n${out}\n${err}")
  endif()
  message(STATUS "consumer test: ${what}: ok")
endfunction()
run_step("install" ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${WORK_DIR}/prefix)
run_step("configure" ${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${WORK_DIR}/build -G ${GENERATOR}
         -DCMAKE_BUILD_TYPE=Release -Ddsr_DIR=${WORK_DIR}/prefix/lib/cmake/dsr
         -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF)
run_step("build" ${CMAKE_COMMAND} --build ${WORK_DIR}/build)
execute_process(COMMAND ${WORK_DIR}/build/consumer RESULT_VARIABLE status)
if(NOT status EQUAL 0)
  message(FATAL_ERROR "consumer test: the consumer program failed (${status})")
endif()
