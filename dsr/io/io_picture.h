// Drawing text and lines on a Picture (OpenCV) and writing it as PNG (libpng); io/ holds
// the only users of OpenCV and ITK.
#ifndef DSR_IO_IO_PICTURE_H_
#define DSR_IO_IO_PICTURE_H_

#include <string>
#include <vector>

#include "dsr/image/picture.h"

namespace dsr {

// Anti-aliased polyline through (x, y) pixel positions.
void DrawPolyline(const std::vector<std::pair<double, double>>& points,
                  Rgb color,
                  int thickness,
                  Picture* picture);
// Text with its baseline-left corner at (x, y); `scale` 0.4 is about 9 pixels high.
void DrawText(const std::string& text, int x, int y, double scale, Rgb color, Picture* picture);
// Writes a PNG atomically (temporary file + rename). Errors name `path`.
bool WritePng(const Picture& picture, const std::string& path, std::string* error);
// Reads a PNG (for tests and tools that check pictures).
bool ReadPng(const std::string& path, Picture* picture, std::string* error);

}  // namespace dsr

#endif  // DSR_IO_IO_PICTURE_H_
