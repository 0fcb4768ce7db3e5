// The errors the module raises: ValueError for bad input (its message naming the Python
// functions' keywords where the library names a field), OSError for a failed write, and
// dsr.RegistrationError (registration_error) for a registration without a result.
#include "module_internal.h"

#include <cstdint>
#include <string>

#include "dsr/app/options.h"

namespace dsr {
namespace python_internal {
namespace {

// The options of the Python functions, by FrontEnd bit: every option of any of them names
// its keyword in a message.
constexpr uint32_t kPythonFrontEnds = kPyRegister | kPyFuse | kPySimulate;

}  // namespace

PyObject* registration_error = nullptr;

[[noreturn]] void BadInput(const std::string& message) {
  throw py::value_error(FieldPathsAsOptions(message, kPythonFrontEnds));
}

std::string AsOptions(const std::string& message) {
  return FieldPathsAsOptions(message, kPythonFrontEnds);
}

[[noreturn]] void WriteFailed(const std::string& message) {
  PyErr_SetString(PyExc_OSError, message.c_str());
  throw py::error_already_set();
}

}  // namespace python_internal
}  // namespace dsr
