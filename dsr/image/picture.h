// An 8-bit RGB picture in plain memory (row-major, 3 bytes per pixel, row 0 at the top),
// the exchange type between the report renderers (pipeline/report.h) and the OpenCV
// adapter (io/io_picture.h), so that only io/ sees OpenCV.
#ifndef DSR_IMAGE_PICTURE_H_
#define DSR_IMAGE_PICTURE_H_

#include <array>
#include <cstdint>
#include <vector>

namespace dsr {

using Rgb = std::array<uint8_t, 3>;

struct Picture {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;  // 3 * width * height

  Picture() = default;
  Picture(int w, int h, Rgb fill = {0, 0, 0}) : width(w), height(h), rgb(3 * size_t(w) * h) {
    for (size_t p = 0; p < size_t(w) * h; ++p) {
      for (int c = 0; c < 3; ++c) rgb[3 * p + c] = fill[c];
    }
  }
  bool Inside(int x, int y) const { return x >= 0 && y >= 0 && x < width && y < height; }
  void Set(int x, int y, Rgb color) {
    if (!Inside(x, y)) return;
    uint8_t* p = &rgb[3 * (size_t(y) * width + x)];
    p[0] = color[0];
    p[1] = color[1];
    p[2] = color[2];
  }
  Rgb Get(int x, int y) const {
    const uint8_t* p = &rgb[3 * (size_t(y) * width + x)];
    return {p[0], p[1], p[2]};
  }
  // Copies `other` with its top-left corner at (x, y) (clipped).
  void Paste(const Picture& other, int x, int y) {
    for (int j = 0; j < other.height; ++j)
      for (int i = 0; i < other.width; ++i) Set(x + i, y + j, other.Get(i, j));
  }
};

}  // namespace dsr

#endif  // DSR_IMAGE_PICTURE_H_
