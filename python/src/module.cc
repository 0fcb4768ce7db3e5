// dsr._core: the C++ side of the Python package (python/dsr/__init__.py is the API users
// call). It is a front end like the command-line tools: options arrive as names and values
// and go through the application layer (dsr/app: the options table's rules and defaults,
// the mapping to RegistrationOptions and SimulationOptions), so a registration from Python
// is the registration dsr_register runs, with its messages. Each call has its own Settings:
// no state is shared between calls, so registrations in several threads do not meet. Only
// conversions live in python/src: this file holds the module's definition (the bindings);
// the functions it binds are in register.cc, simulate.cc, fuse.cc, files.cc and options.cc,
// their helpers in errors.cc, options.cc, convert.cc, summary.cc and inputs.cc, and what
// they share in module_internal.h.
#include "module_internal.h"

#include <stdexcept>

#include "dsr/solve/solve_options.h"

namespace py = pybind11;
namespace internal = dsr::python_internal;

PYBIND11_MODULE(_core, m) {
  m.doc() = "C++ core of the dsr package (see dsr/__init__.py for the API).";
  static py::exception<std::runtime_error> error(m, "RegistrationError", PyExc_RuntimeError);
  internal::registration_error = error.ptr();
  py::class_<dsr::IterationRecord>(m, "IterationRecord")
      .def_readonly("iteration", &dsr::IterationRecord::iteration)
      .def_readonly("cost", &dsr::IterationRecord::cost)
      .def_readonly("step_norm", &dsr::IterationRecord::step_norm)
      .def_readonly("seconds", &dsr::IterationRecord::seconds)
      .def_readonly("step_accepted", &dsr::IterationRecord::step_accepted);
  m.def("register", &internal::RegisterImages, py::arg("images"), py::arg("masks"),
        py::arg("names"), py::arg("options"), py::arg("initial_poses"), py::arg("on_iteration"));
  m.def("simulate", &internal::SimulateSequence, py::arg("options"));
  m.def("register_files", &internal::RegisterFiles, py::arg("options"));
  m.def("check_register_options", &internal::CheckRegisterOptions, py::arg("options"));
  m.def("check_register_files", &internal::CheckRegisterFiles, py::arg("options"));
  m.def("init_is_file", &internal::InitIsFile, py::arg("text"));
  m.def("fuse", &internal::FuseImages, py::arg("images"), py::arg("masks"), py::arg("names"),
        py::arg("poses"), py::arg("options"));
  m.def("write_tfm", &internal::WriteTransformFile, py::arg("pose"), py::arg("path"));
  m.def("read_image", &internal::ReadImageFile, py::arg("path"));
  m.def("write_image", &internal::WriteImageFile, py::arg("array"), py::arg("geometry"),
        py::arg("path"));
  m.def("read_poses", &internal::ReadPosesFile, py::arg("path"), py::arg("expected_frames") = -1);
  m.def("write_poses", &internal::WritePosesFile, py::arg("poses"), py::arg("path"));
  m.def("options", &internal::OptionsTable);
}
