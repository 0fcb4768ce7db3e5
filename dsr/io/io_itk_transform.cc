// ITK transform files, Eigen-free like io_itk.cc (see io_itk.h).
#include <exception>
#include <string>

#include <itkAffineTransform.h>
#include <itkMatrixOffsetTransformBase.h>
#include <itkTransformFactoryBase.h>
#include <itkTransformFileReader.h>
#include <itkTransformFileWriter.h>
#include <itkTxtTransformIOFactory.h>

#include "dsr/io/io_itk.h"

namespace dsr {
namespace itk_io {
namespace {

// ITK's text transform IO (.tfm, .txt), registered once (without it the factory finds no
// writer: "There are no registered Transform IO factories").
void RegisterTransformIo() {
  static const bool registered = [] {
    itk::TxtTransformIOFactory::RegisterOneFactory();
    itk::TransformFactoryBase::RegisterDefaultTransforms();
    return true;
  }();
  (void)registered;
}

}  // namespace


bool WriteAffineTransform(const std::string& path, const double matrix[12], std::string* error) {
  RegisterTransformIo();
  try {
    using Affine = itk::AffineTransform<double, 3>;
    Affine::Pointer transform = Affine::New();
    Affine::MatrixType a;
    Affine::OutputVectorType b;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) a(r, c) = matrix[4 * r + c];
      b[r] = matrix[4 * r + 3];
    }
    transform->SetMatrix(a);
    transform->SetOffset(b);
    auto writer = itk::TransformFileWriterTemplate<double>::New();
    writer->SetFileName(path);
    writer->SetInput(transform);
    writer->Update();
    return true;
  } catch (const std::exception& e) {
    std::string what = e.what();
    const size_t nl = what.find_last_not_of(" \n");
    *error = path + ": cannot write the transform (" + what.substr(0, nl + 1) + ")";
    for (char& c : *error) if (c == '\n') c = ' ';
    return false;
  }
}

bool ReadAffineTransform(const std::string& path, double matrix[12], std::string* error) {
  RegisterTransformIo();
  try {
    auto reader = itk::TransformFileReaderTemplate<double>::New();
    reader->SetFileName(path);
    reader->Update();
    const auto* list = reader->GetTransformList();
    if (list == nullptr || list->empty()) {
      *error = path + ": no transform in the file";
      return false;
    }
    using Base = itk::MatrixOffsetTransformBase<double, 3, 3>;
    const auto* transform = dynamic_cast<const Base*>(list->front().GetPointer());
    if (transform == nullptr) {
      *error = path + ": the first transform (" + list->front()->GetNameOfClass() +
               ") is not a 3D matrix-offset transform";
      return false;
    }
    const auto& a = transform->GetMatrix();
    const auto& b = transform->GetOffset();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) matrix[4 * r + c] = a(r, c);
      matrix[4 * r + 3] = b[r];
    }
    return true;
  } catch (const std::exception& e) {
    std::string what = e.what();
    for (char& c : what) if (c == '\n') c = ' ';
    *error = path + ": cannot read the transform (" + what + ")";
    return false;
  }
}

}  // namespace itk_io
}  // namespace dsr
