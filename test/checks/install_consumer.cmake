# cmake -DBUILD_DIR=... -DWORK_DIR=... -DCONSUMER_SOURCE_DIR=... -DCXX_COMPILER=... -DC_COMPILER=...
#       -DGENERATOR=... -DBUILD_TYPE=... [-DCONSUMER_FLAGS=...] -P install_consumer.cmake
# Installs the built project into a fresh prefix, then configures, builds and runs a small
# project that only knows `find_package(octofuse COMPONENTS <ports>)` and the octofuse:: targets,
# and the minimal example (examples/minimal) the same way.
#   [-DPORTS=sim|host|...] the ports built, each expected as a component
#   [-DMINIMAL_SOURCE_DIR=...] examples/minimal, built and run against the install when given
foreach(var BUILD_DIR WORK_DIR CONSUMER_SOURCE_DIR CXX_COMPILER C_COMPILER GENERATOR)
  if(NOT ${var})
    message(FATAL_ERROR "install_consumer: ${var} is required")
  endif()
endforeach()
if(NOT BUILD_TYPE)
  set(BUILD_TYPE Release)
endif()

function(run_step what)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE result OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT result EQUAL 0)
    message(FATAL_ERROR "install_consumer: ${what} failed (${result})\n${out}\n${err}")
  endif()
  message(STATUS "install_consumer: ${what}: ok")
  set(step_output "${out}" PARENT_SCOPE)
endfunction()

string(REPLACE "|" ";" ports "${PORTS}")
file(REMOVE_RECURSE ${WORK_DIR})
set(prefix ${WORK_DIR}/prefix)
set(consumer_build ${WORK_DIR}/build)

run_step("install" ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${prefix} --config ${BUILD_TYPE})
if(NOT EXISTS ${prefix}/include/octofuse/core/status.hpp)
  message(FATAL_ERROR "install_consumer: headers missing from ${prefix}/include")
endif()

run_step("configure consumer"
         ${CMAKE_COMMAND} -S ${CONSUMER_SOURCE_DIR} -B ${consumer_build} -G ${GENERATOR}
         -DCMAKE_BUILD_TYPE=${BUILD_TYPE} -DCMAKE_PREFIX_PATH=${prefix}
         -DCMAKE_CXX_COMPILER=${CXX_COMPILER} -DCMAKE_C_COMPILER=${C_COMPILER}
         "-DCMAKE_CXX_FLAGS=${CONSUMER_FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${CONSUMER_FLAGS}"
         "-DOCTOFUSE_PORTS=${ports}")
run_step("build consumer" ${CMAKE_COMMAND} --build ${consumer_build})
run_step("run consumer" ${consumer_build}/octofuse_consumer)
message(STATUS "${step_output}")

if(MINIMAL_SOURCE_DIR)
  set(minimal_build ${WORK_DIR}/minimal)
  run_step("configure examples/minimal"
           ${CMAKE_COMMAND} -S ${MINIMAL_SOURCE_DIR} -B ${minimal_build} -G ${GENERATOR}
           -DCMAKE_BUILD_TYPE=${BUILD_TYPE} -DCMAKE_PREFIX_PATH=${prefix}
           -DCMAKE_CXX_COMPILER=${CXX_COMPILER} -DCMAKE_C_COMPILER=${C_COMPILER}
           "-DCMAKE_CXX_FLAGS=${CONSUMER_FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${CONSUMER_FLAGS}")
  run_step("build examples/minimal" ${CMAKE_COMMAND} --build ${minimal_build})
  run_step("run examples/minimal" ${minimal_build}/octofuse-minimal)
  message(STATUS "${step_output}")
  # The sim desk seen for 60 frames: every frame tracked, and the air halfway to the surface
  # ahead was seen free.
  if(NOT step_output MATCHES "^60 of 60 frames tracked" OR NOT step_output MATCHES "ahead is free;")
    message(FATAL_ERROR "install_consumer: examples/minimal answered otherwise: ${step_output}")
  endif()
endif()
