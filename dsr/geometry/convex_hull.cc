// qhull's convex hull as half-spaces (geometry/convex_hull.h). This file is kept out of
// the library's unity build: qhull's headers define macros (True, False, boolT, ...) that
// must not reach other sources.
#include "dsr/geometry/convex_hull.h"

#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>

extern "C" {
#include <libqhull_r/libqhull_r.h>
}

namespace dsr {
namespace {

// qhull's messages go to a FILE*; this one holds them in memory, so that a failure is
// reported to the caller instead of printed on stderr.
class MemoryFile {
 public:
  MemoryFile() : file_(open_memstream(&buffer_, &size_)) {}
  ~MemoryFile() {
    if (file_ != nullptr) std::fclose(file_);
    std::free(buffer_);
  }
  MemoryFile(const MemoryFile&) = delete;
  MemoryFile& operator=(const MemoryFile&) = delete;

  FILE* file() const { return file_; }
  // The first line written so far.
  std::string FirstLine() {
    if (file_ == nullptr) return "";
    std::fflush(file_);
    const std::string text(buffer_ != nullptr ? buffer_ : "", size_);
    return text.substr(0, text.find('\n'));
  }

 private:
  char* buffer_ = nullptr;
  size_t size_ = 0;
  FILE* file_ = nullptr;
};

}  // namespace

bool ConvexHullHalfSpaces(const std::vector<double>& xyz,
                          std::vector<HalfSpace>* half_spaces,
                          std::string* error) {
  half_spaces->clear();
  const int num_points = static_cast<int>(xyz.size() / 3);
  if (num_points < 4) {
    *error = "fewer than 4 points (" + std::to_string(num_points) + ")";
    return false;
  }
  // qhull takes its input as a mutable array; it does not keep it past qh_freeqhull.
  std::vector<coordT> points(xyz.begin(), xyz.end());
  // The default options: coplanar facets are merged ('C-0'), so a face of a lattice
  // staircase becomes one half-space, not many triangles.
  char command[] = "qhull";
  MemoryFile messages;
  // qhT is large (tens of kB): on the heap, not on a worker thread's stack. `qh` is the
  // name qhull's macros (FORALLfacets) expect.
  const auto state = std::make_unique<qhT>();
  qhT* qh = state.get();
  qh_zero(qh, messages.file());
  const int exit_code =
      qh_new_qhull(qh, 3, num_points, points.data(), False, command, nullptr, messages.file());
  if (exit_code == qh_ERRnone) {
    facetT* facet;
    FORALLfacets {
      half_spaces->emplace_back(facet->normal[0], facet->normal[1], facet->normal[2],
                                facet->offset);
    }
  } else {
    *error = "qhull failed (exit code " + std::to_string(exit_code) + "): " +
             messages.FirstLine();
  }
  qh_freeqhull(qh, !qh_ALL);
  int still_allocated = 0, total_allocated = 0;
  qh_memfreeshort(qh, &still_allocated, &total_allocated);
  return exit_code == qh_ERRnone && !half_spaces->empty();
}

}  // namespace dsr
