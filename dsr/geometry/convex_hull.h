// The convex hull of a 3D point set as half-spaces, computed by qhull (libqhull_r, the
// reentrant C library: one qhull instance per call, so calls may run in parallel). Used by
// the field-of-view rule of frames given without a mask (geometry/field_of_view.h,
// docs/design.md section 2.1).
#ifndef DSR_GEOMETRY_CONVEX_HULL_H_
#define DSR_GEOMETRY_CONVEX_HULL_H_

#include <string>
#include <vector>

#include <Eigen/Core>

namespace dsr {

// One facet's half-space {x : normal . x + offset <= 0}, stored as [normal (unit, pointing
// out of the hull); offset].
using HalfSpace = Eigen::Vector4d;

// The facets of the convex hull of `xyz` (x, y, z of each point, in any unit): the hull is
// the intersection of `half_spaces`, and every input point lies in each of them up to
// qhull's rounding (about 1e-13 of the coordinates' magnitude). Coplanar facets are merged.
// False, with `error` holding qhull's first message line, when the points span fewer than
// 3 dimensions (fewer than 4 points, all on one plane) or qhull fails.
bool ConvexHullHalfSpaces(const std::vector<double>& xyz,
                          std::vector<HalfSpace>* half_spaces,
                          std::string* error);

}  // namespace dsr

#endif  // DSR_GEOMETRY_CONVEX_HULL_H_
