// ITK image reading and writing with plain arrays (see io_itk.h for why no Eigen here).
#include "core/io_itk.h"

#include <algorithm>
#include <filesystem>
#include <mutex>

#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkImageIOBase.h>
#include <itkImageIOFactory.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>

namespace dsr {
namespace itk_io {
namespace {

void RegisterFactories() {
  static std::once_flag once;
  std::call_once(once, [] {
    itk::NiftiImageIOFactory::RegisterOneFactory();
    itk::MetaImageIOFactory::RegisterOneFactory();
    itk::NrrdImageIOFactory::RegisterOneFactory();
  });
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// ITK messages span several lines: keep the description on one line.
std::string OneLine(const itk::ExceptionObject& e) {
  std::string what = e.GetDescription();
  std::replace(what.begin(), what.end(), '\n', ' ');
  what.erase(std::unique(what.begin(), what.end(), [](char a, char b) { return a == ' ' && b == ' '; }),
             what.end());
  while (!what.empty() && what.back() == ' ') what.pop_back();
  return what;
}

bool Inspect(const std::string& path, std::string* error, unsigned* num_dims) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    *error = path + ": no such file";
    return false;
  }
  if (!std::filesystem::is_regular_file(path, ec)) {
    *error = path + ": not a regular file";
    return false;
  }
  RegisterFactories();
  itk::ImageIOBase::Pointer io =
      itk::ImageIOFactory::CreateImageIO(path.c_str(), itk::ImageIOFactory::FileModeEnum::ReadMode);
  if (!io) {
    *error = path + ": not a readable image (corrupt or unknown header)";
    return false;
  }
  try {
    io->SetFileName(path);
    io->ReadImageInformation();
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot read the header (" + OneLine(e) + ")";
    return false;
  }
  const unsigned components = io->GetNumberOfComponents();
  const auto pixel = io->GetPixelType();
  if (components != 1 || pixel != itk::IOPixelEnum::SCALAR) {
    *error = path + ": " + itk::ImageIOBase::GetPixelTypeAsString(pixel) + " pixels with " +
             std::to_string(components) + " components; expected a scalar image";
    return false;
  }
  *num_dims = io->GetNumberOfDimensions();
  size_t volumes = 1;
  for (unsigned d = 3; d < *num_dims; ++d) volumes *= io->GetDimensions(d);
  if (*num_dims < 3) {
    *error = path + ": " + std::to_string(*num_dims) + "D image; expected 3D";
    return false;
  }
  if (*num_dims > 4 || volumes != 1) {
    *error = path + ": " + std::to_string(*num_dims) + "D image with " + std::to_string(volumes) +
             " volumes; expected one 3D volume";
    return false;
  }
  return true;
}

template <unsigned Dim>
bool ReadAs(const std::string& path, RawVolume* out, std::string* error) {
  using ItkImage = itk::Image<float, Dim>;
  auto reader = itk::ImageFileReader<ItkImage>::New();
  reader->SetFileName(path);
  try {
    reader->Update();
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot read the voxels (" + OneLine(e) + ")";
    return false;
  }
  const ItkImage* image = reader->GetOutput();
  const auto size = image->GetLargestPossibleRegion().GetSize();
  size_t n = 1;
  for (int a = 0; a < 3; ++a) {
    out->size[a] = static_cast<int>(size[a]);
    out->origin[a] = image->GetOrigin()[a];
    out->spacing[a] = image->GetSpacing()[a];
    for (int b = 0; b < 3; ++b) out->direction[3 * a + b] = image->GetDirection()[a][b];
    n *= size[a];
  }
  const float* data = image->GetBufferPointer();
  out->voxels.assign(data, data + n);
  return true;
}

template <typename Pixel>
bool WriteAs(const RawVolume& volume, const std::string& path, std::string* error) {
  using ItkImage = itk::Image<Pixel, 3>;
  RegisterFactories();
  auto image = ItkImage::New();
  typename ItkImage::RegionType region;
  typename ItkImage::SpacingType spacing;
  typename ItkImage::PointType origin;
  typename ItkImage::DirectionType direction;
  for (int a = 0; a < 3; ++a) {
    region.SetSize(a, volume.size[a]);
    spacing[a] = volume.spacing[a];
    origin[a] = volume.origin[a];
    for (int b = 0; b < 3; ++b) direction[a][b] = volume.direction[3 * a + b];
  }
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
  image->Allocate();
  std::transform(volume.voxels.begin(), volume.voxels.end(), image->GetBufferPointer(),
                 [](float v) { return static_cast<Pixel>(v); });
  auto writer = itk::ImageFileWriter<ItkImage>::New();
  writer->SetFileName(path);
  writer->SetInput(image);
  writer->SetUseCompression(EndsWith(path, ".gz") || EndsWith(path, ".mha") || EndsWith(path, ".nrrd"));
  try {
    writer->Update();
  } catch (const itk::ExceptionObject& e) {
    *error = path + ": cannot write (" + OneLine(e) + ")";
    return false;
  }
  return true;
}

}  // namespace

bool Read(const std::string& path, RawVolume* volume, std::string* error) {
  unsigned num_dims = 0;
  if (!Inspect(path, error, &num_dims)) return false;
  return num_dims == 3 ? ReadAs<3>(path, volume, error) : ReadAs<4>(path, volume, error);
}

bool Write(const RawVolume& volume, const std::string& path, bool as_bytes, std::string* error) {
  return as_bytes ? WriteAs<unsigned char>(volume, path, error) : WriteAs<float>(volume, path, error);
}

}  // namespace itk_io
}  // namespace dsr
