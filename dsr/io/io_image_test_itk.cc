// Test-only ITK writers (see io_image_test_itk.h).
#include "dsr/io/io_image_test_itk.h"

#include <cstdint>
#include <exception>
#include <type_traits>

#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkLinearInterpolateImageFunction.h>
#include <itkResampleImageFilter.h>
#include <itkTransform.h>
#include <itkTransformFactoryBase.h>
#include <itkTransformFileReader.h>
#include <itkTxtTransformIOFactory.h>
#include <itkMetaImageIO.h>
#include <itkNiftiImageIO.h>
#include <itkNrrdImageIO.h>
#include <itkVector.h>
#include <itkVectorImage.h>

#include "dsr/util/text.h"

namespace dsr {
namespace test_itk {
namespace {

// The IO is chosen explicitly, so these writers do not depend on factory registration.
itk::ImageIOBase::Pointer IoFor(const std::string& path) {
  if (EndsWith(path, ".nii") || EndsWith(path, ".nii.gz"))
    return itk::NiftiImageIO::New().GetPointer();
  if (EndsWith(path, ".mha") || EndsWith(path, ".mhd")) return itk::MetaImageIO::New().GetPointer();
  return itk::NrrdImageIO::New().GetPointer();
}

template <typename PixelType, unsigned Dim>
std::string WriteImage(const std::string& path,
                       const Grid& grid,
                       const std::vector<double>* values,
                       const PixelType& fill) {
  using ImageType = itk::Image<PixelType, Dim>;
  if (grid.size.size() != Dim) return "grid has " + std::to_string(grid.size.size()) + " sizes";
  auto image = ImageType::New();
  typename ImageType::RegionType region;
  typename ImageType::SpacingType spacing;
  typename ImageType::PointType origin;
  typename ImageType::DirectionType direction;
  direction.SetIdentity();
  spacing.Fill(1.0);
  origin.Fill(0.0);
  for (unsigned a = 0; a < Dim; ++a) {
    region.SetSize(a, grid.size[a]);
    if (a >= 3) continue;
    spacing[a] = grid.spacing[a];
    origin[a] = grid.origin[a];
    for (unsigned b = 0; b < Dim && b < 3; ++b) direction[a][b] = grid.direction[3 * a + b];
  }
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
  image->Allocate();
  image->FillBuffer(fill);
  if constexpr (std::is_arithmetic_v<PixelType>) {
    if (values != nullptr) {
      const size_t n = image->GetLargestPossibleRegion().GetNumberOfPixels();
      if (values->size() != n) return "expected " + std::to_string(n) + " values";
      PixelType* buffer = image->GetBufferPointer();
      for (size_t v = 0; v < n; ++v) buffer[v] = static_cast<PixelType>((*values)[v]);
    }
  }
  auto writer = itk::ImageFileWriter<ImageType>::New();
  writer->SetImageIO(IoFor(path));
  writer->SetFileName(path);
  writer->SetInput(image);
  writer->SetUseCompression(EndsWith(path, ".gz"));
  try {
    writer->Update();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

template <typename PixelType>
std::string WriteScalar(const std::string& path,
                        const Grid& grid,
                        const std::vector<double>& values) {
  switch (grid.size.size()) {
    case 2:
      return WriteImage<PixelType, 2>(path, grid, &values, PixelType{});
    case 3:
      return WriteImage<PixelType, 3>(path, grid, &values, PixelType{});
    case 4:
      return WriteImage<PixelType, 4>(path, grid, &values, PixelType{});
    default:
      return "unsupported dimension " + std::to_string(grid.size.size());
  }
}

}  // namespace

std::string WriteScalarImage(const std::string& path,
                             const Grid& grid,
                             Pixel pixel,
                             const std::vector<double>& values) {
  switch (pixel) {
    case Pixel::kUint8:
      return WriteScalar<uint8_t>(path, grid, values);
    case Pixel::kInt16:
      return WriteScalar<int16_t>(path, grid, values);
    case Pixel::kFloat:
      return WriteScalar<float>(path, grid, values);
    case Pixel::kDouble:
      return WriteScalar<double>(path, grid, values);
  }
  return "unknown pixel type";
}

std::string WriteVectorImage(const std::string& path, const Grid& grid) {
  itk::Vector<float, 3> fill;
  fill[0] = 1.0f;
  fill[1] = 2.0f;
  fill[2] = 3.0f;
  return WriteImage<itk::Vector<float, 3>, 3>(path, grid, nullptr, fill);
}

std::string ReadPhasesWithItk(const std::string& path, std::vector<std::vector<float>>* phases) {
  try {
    itk::ImageIOBase::Pointer io = IoFor(path);
    io->SetFileName(path);
    io->ReadImageInformation();
    if (io->GetNumberOfComponents() > 1) {
      using ImageType = itk::VectorImage<float, 3>;
      auto reader = itk::ImageFileReader<ImageType>::New();
      reader->SetImageIO(IoFor(path));
      reader->SetFileName(path);
      reader->Update();
      const ImageType* image = reader->GetOutput();
      const size_t n = image->GetLargestPossibleRegion().GetNumberOfPixels();
      const size_t count = image->GetNumberOfComponentsPerPixel();
      phases->assign(count, std::vector<float>(n));
      const float* buffer = image->GetBufferPointer();
      for (size_t v = 0; v < n; ++v) {
        for (size_t t = 0; t < count; ++t) (*phases)[t][v] = buffer[v * count + t];
      }
      return "";
    }
    using ImageType = itk::Image<float, 4>;
    auto reader = itk::ImageFileReader<ImageType>::New();
    reader->SetImageIO(IoFor(path));
    reader->SetFileName(path);
    reader->Update();
    const ImageType* image = reader->GetOutput();
    const ImageType::SizeType size = image->GetLargestPossibleRegion().GetSize();
    const size_t n = static_cast<size_t>(size[0]) * size[1] * size[2];
    const float* buffer = image->GetBufferPointer();
    phases->clear();
    for (size_t t = 0; t < size[3]; ++t) phases->emplace_back(buffer + t * n, buffer + (t + 1) * n);
    return "";
  } catch (const std::exception& e) {
    return e.what();
  }
}

std::string ResampleWithTransformFile(const std::string& image_path,
                                      const std::string& transform_path,
                                      const Grid& grid,
                                      std::vector<float>* voxels) {
  try {
    using ImageType = itk::Image<float, 3>;
    auto reader = itk::ImageFileReader<ImageType>::New();
    reader->SetImageIO(IoFor(image_path));
    reader->SetFileName(image_path);
    reader->Update();
    static const bool registered = [] {
      itk::TxtTransformIOFactory::RegisterOneFactory();
      return true;
    }();
    (void)registered;
    itk::TransformFactoryBase::RegisterDefaultTransforms();
    auto transform_reader = itk::TransformFileReaderTemplate<double>::New();
    transform_reader->SetFileName(transform_path);
    transform_reader->Update();
    using TransformType = itk::Transform<double, 3, 3>;
    auto* transform =
        dynamic_cast<TransformType*>(transform_reader->GetTransformList()->front().GetPointer());
    if (transform == nullptr) return "not a 3D transform";
    auto resample = itk::ResampleImageFilter<ImageType, ImageType>::New();
    resample->SetInput(reader->GetOutput());
    resample->SetTransform(transform);
    resample->SetInterpolator(itk::LinearInterpolateImageFunction<ImageType, double>::New());
    resample->SetDefaultPixelValue(0.0f);
    ImageType::SizeType size;
    ImageType::PointType origin;
    ImageType::SpacingType spacing;
    ImageType::DirectionType direction;
    for (int a = 0; a < 3; ++a) {
      size[a] = grid.size[a];
      origin[a] = grid.origin[a];
      spacing[a] = grid.spacing[a];
      for (int b = 0; b < 3; ++b) direction(a, b) = grid.direction[3 * a + b];
    }
    resample->SetSize(size);
    resample->SetOutputOrigin(origin);
    resample->SetOutputSpacing(spacing);
    resample->SetOutputDirection(direction);
    resample->Update();
    const ImageType* out = resample->GetOutput();
    const size_t n = static_cast<size_t>(size[0]) * size[1] * size[2];
    voxels->assign(out->GetBufferPointer(), out->GetBufferPointer() + n);
    return "";
  } catch (const std::exception& e) {
    return e.what();
  }
}

}  // namespace test_itk
}  // namespace dsr
