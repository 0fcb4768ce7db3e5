#include "dsr/pipeline/registration_options.h"

#include <cmath>
#include <string>

#include "dsr/pipeline/modes.h"
#include "dsr/util/option_fields.h"

namespace dsr {

bool StringToPhotometricModel(const std::string& name, PhotometricModel* model) {
  return FindNamed(name,
                   {PhotometricModel::kNone, PhotometricModel::kAffine, PhotometricModel::kAuto},
                   PhotometricModelToString, model);
}

namespace {

// The pyramid's and the candidate rebuilds' rules of RegistrationOptions::Validate.
bool ValidateLevels(const RegistrationOptions& o, std::string* error) {
  if (!(o.panorama_spacing > 0.0) || !std::isfinite(o.panorama_spacing)) {
    return RefuseField(error, "panorama_spacing", o.panorama_spacing, "must be a positive number");
  }
  if (o.pyramid_levels < 1 || o.pyramid_levels > 8) {
    return RefuseField(error, "pyramid_levels", o.pyramid_levels, "must be in 1..8");
  }
  if (!(o.pyramid_sigma >= 0.0) || !std::isfinite(o.pyramid_sigma)) {
    return RefuseField(error, "pyramid_sigma", o.pyramid_sigma, "must be >= 0");
  }
  if (!(o.smoothing >= 0.0) || !std::isfinite(o.smoothing)) {
    return RefuseField(error, "smoothing", o.smoothing, "must be >= 0");
  }
  if (o.pyramid_min_size < 4) {
    return RefuseField(error, "pyramid_min_size", o.pyramid_min_size, "must be >= 4");
  }
  if (o.coarse_max_iterations < 1) {
    return RefuseField(error, "coarse_max_iterations", o.coarse_max_iterations, "must be >= 1");
  }
  if (o.max_rebuilds < 0) return RefuseField(error, "max_rebuilds", o.max_rebuilds, "must be >= 0");
  if (!(o.rebuild_tolerance > 0.0 && std::isfinite(o.rebuild_tolerance))) {
    return RefuseField(error, "rebuild_tolerance", o.rebuild_tolerance, "must be finite and > 0");
  }
  if (!(o.unsettled_motion_voxels >= 0.0 && std::isfinite(o.unsettled_motion_voxels))) {
    return RefuseField(error, "unsettled_motion_voxels", o.unsettled_motion_voxels,
                       "must be finite and >= 0");
  }
  return true;
}

// The checks' and the recovery's rules of RegistrationOptions::Validate.
bool ValidateChecks(const RegistrationOptions& o, std::string* error) {
  if (!(o.min_kept_overlap >= 0.0 && o.min_kept_overlap < 1.0)) {
    return RefuseField(error, "min_kept_overlap", o.min_kept_overlap, "must be in [0, 1)");
  }
  if (!(o.max_misfit_ratio == 0.0 ||
        (o.max_misfit_ratio > 1.0 && std::isfinite(o.max_misfit_ratio)))) {
    return RefuseField(error, "max_misfit_ratio", o.max_misfit_ratio, "must be 0 (off) or > 1");
  }
  if (!(o.max_pose_error_voxels >= 0.0 && std::isfinite(o.max_pose_error_voxels))) {
    return RefuseField(error, "max_pose_error_voxels", o.max_pose_error_voxels,
                       "must be >= 0 (0: off)");
  }
  if (!(o.max_structure_fraction >= 0.0 && o.max_structure_fraction < 1.0)) {
    return RefuseField(error, "max_structure_fraction", o.max_structure_fraction,
                       "must be in [0, 1) (0: off)");
  }
  if (!(o.max_pair_mismatch_ratio == 0.0 ||
        (o.max_pair_mismatch_ratio > 1.0 && std::isfinite(o.max_pair_mismatch_ratio)))) {
    return RefuseField(error, "max_pair_mismatch_ratio", o.max_pair_mismatch_ratio,
                       "must be 0 (off) or > 1");
  }
  if (o.min_shared_voxels < 1) {
    return RefuseField(error, "min_shared_voxels", o.min_shared_voxels, "must be >= 1");
  }
  if (o.max_recoveries < 0 || o.max_recoveries > 10) {
    return RefuseField(error, "max_recoveries", o.max_recoveries, "must be in [0, 10]");
  }
  if (o.max_recoveries > 0 && o.max_misfit_ratio == 0.0 && o.min_kept_overlap == 0.0 &&
      o.max_pair_mismatch_ratio == 0.0 && o.max_structure_fraction == 0.0) {
    return RefuseField(error, "max_recoveries", o.max_recoveries,
                       "recovery needs a check that flags frames, but max_misfit_ratio=0, "
                       "max_pair_mismatch_ratio=0, max_structure_fraction=0 and "
                       "min_kept_overlap=0");
  }
  return true;
}

}  // namespace

bool RegistrationOptions::Validate(std::string* error) const {
  if (ModeToString(mode)[0] == '\0') {
    return RefuseField(error, "mode", static_cast<int>(mode), "unknown mode");
  }
  if (!solve.Validate(error)) {
    *error = PrefixFieldPaths("solve", *error);
    return false;
  }
  if (!ValidateLevels(*this, error) || !ValidateChecks(*this, error)) return false;
  if (search_max_axis < 8) {
    return RefuseField(error, "search_max_axis", search_max_axis, "must be >= 8");
  }
  if ((max_recoveries > 0 || init == InitialPoses::kGlobal) && !search.Validate(error)) {
    *error = PrefixFieldPaths("search", *error);
    return false;
  }
  if (!loss.Validate(error)) {
    *error = PrefixFieldPaths("loss", *error);
    return false;
  }
  if (!loss.IsSquared() && !ModeEstimatesPhotometric(mode)) {
    return RefuseField(error, "loss.kind", RobustLossKindName(loss.kind),
                       "needs mode=dsr or dba (mode=" + std::string(ModeToString(mode)) +
                           " is a baseline with squared differences)");
  }
  const bool affine = photometric != PhotometricModel::kNone;
  if (affine && !ModeEstimatesPhotometric(mode)) {
    return RefuseField(error, "photometric", PhotometricModelToString(photometric),
                       "needs mode=dsr or dba (mode=" + std::string(ModeToString(mode)) +
                           " is a baseline without photometric parameters; use photometric=none)");
  }
  if (uncertainty && !ModeEstimatesPhotometric(mode)) {
    return RefuseField(error, "uncertainty", "true",
                       "needs mode=dsr or dba (mode=" + std::string(ModeToString(mode)) +
                           " is a baseline, whose poses the estimate does not model)");
  }
  // Each solver's own rules first without the photometric parameters, so that an error of
  // theirs with them is the photometric field's.
  if (ModeEstimatesPhotometric(mode)) {
    const auto valid = [&](const RegistrationOptions& o) {
      return mode == Mode::kDsr ? ToDsrOptions(o, solve).Validate(error)
                                : ToDbaOptions(o, solve).Validate(error);
    };
    RegistrationOptions plain = *this;
    plain.photometric = PhotometricModel::kNone;
    if (!valid(plain)) return false;
    RegistrationOptions with = *this;
    with.photometric = PhotometricModel::kAffine;
    if (affine && !valid(with)) {
      *error = "photometric=" + std::string(PhotometricModelToString(photometric)) + ": " + *error;
      return false;
    }
  } else if (!ToBaselineOptions(*this, solve).Validate(error)) {
    return false;
  }
  return true;
}

}  // namespace dsr
