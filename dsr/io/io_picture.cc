#include "dsr/io/io_picture.h"

#include <png.h>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "dsr/util/atomic_file.h"

namespace dsr {
namespace {

// A BGR view of the picture's RGB memory is not possible (channel order), so drawing goes
// through a converted copy.
cv::Mat ToBgr(const Picture& picture) {
  cv::Mat rgb(picture.height, picture.width, CV_8UC3, const_cast<uint8_t*>(picture.rgb.data()));
  cv::Mat bgr;
  cv::cvtColor(rgb, bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

void FromBgr(const cv::Mat& bgr, Picture* picture) {
  cv::Mat rgb;
  cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
  picture->width = rgb.cols;
  picture->height = rgb.rows;
  picture->rgb.assign(rgb.data, rgb.data + 3 * size_t(rgb.cols) * rgb.rows);
}

cv::Scalar Bgr(Rgb c) { return cv::Scalar(c[2], c[1], c[0]); }

}  // namespace

void DrawPolyline(const std::vector<std::pair<double, double>>& points,
                  Rgb color,
                  int thickness,
                  Picture* picture) {
  if (points.size() < 2 || picture->width == 0) return;
  cv::Mat bgr = ToBgr(*picture);
  constexpr int kShift = 4;  // sub-pixel precision
  std::vector<cv::Point> pts;
  for (const auto& [x, y] : points) {
    pts.emplace_back(cvRound(x * (1 << kShift)), cvRound(y * (1 << kShift)));
  }
  cv::polylines(bgr, pts, false, Bgr(color), thickness, cv::LINE_AA, kShift);
  FromBgr(bgr, picture);
}

void DrawText(const std::string& text, int x, int y, double scale, Rgb color, Picture* picture) {
  if (picture->width == 0) return;
  cv::Mat bgr = ToBgr(*picture);
  cv::putText(bgr, text, cv::Point(x, y), cv::FONT_HERSHEY_SIMPLEX, scale, Bgr(color), 1,
              cv::LINE_AA);
  FromBgr(bgr, picture);
}

// PNG files through libpng's simplified API (8-bit RGB, no alpha): OpenCV's codecs would pull
// in GDAL and about a hundred more libraries, 60 ms of every tool's start-up.
bool WritePng(const Picture& picture, const std::string& path, std::string* error) {
  if (picture.width <= 0 || picture.height <= 0) {
    *error = path + ": empty picture";
    return false;
  }
  return WriteViaTemporaryFile(
      path,
      [&](const std::string& temp, std::string* e) {
        png_image image{};
        image.version = PNG_IMAGE_VERSION;
        image.width = static_cast<png_uint_32>(picture.width);
        image.height = static_cast<png_uint_32>(picture.height);
        image.format = PNG_FORMAT_RGB;
        if (png_image_write_to_file(&image, temp.c_str(), 0, picture.rgb.data(),
                                    3 * picture.width, nullptr) != 0) {
          return true;
        }
        *e = temp + ": cannot write the PNG (" + image.message + ")";
        png_image_free(&image);
        return false;
      },
      error);
}

bool ReadPng(const std::string& path, Picture* picture, std::string* error) {
  png_image image{};
  image.version = PNG_IMAGE_VERSION;
  if (png_image_begin_read_from_file(&image, path.c_str()) == 0) {
    *error = path + ": cannot read the picture (" + image.message + ")";
    png_image_free(&image);
    return false;
  }
  image.format = PNG_FORMAT_RGB;  // grey, palette and alpha converted (alpha over black)
  std::vector<uint8_t> rgb(PNG_IMAGE_SIZE(image));
  if (png_image_finish_read(&image, nullptr, rgb.data(), 0, nullptr) == 0) {
    *error = path + ": cannot read the picture (" + image.message + ")";
    png_image_free(&image);
    return false;
  }
  picture->width = static_cast<int>(image.width);
  picture->height = static_cast<int>(image.height);
  picture->rgb = std::move(rgb);
  return true;
}

}  // namespace dsr
