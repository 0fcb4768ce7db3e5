// The paper's simulation protocol (docs/design.md section 6): frames cut from a source volume
// with a TEE-like pyramidal field of view at random rigid poses, intensities 0..255,
// additive Gaussian noise inside the field of view, zero outside.
//
// Frame geometry: `frame_size` voxels, isotropic spacing s (frame_spacing, or the
// source's spacing along its first axis), origin 0, identity direction: the probe's own
// coordinates. The pyramid's apex is the centre of the k = 0 face, depth runs along +k.
// A voxel (i, j, k) is in the field of view when
//   k >= min_depth_voxels,  |i - cx| <= k tan(azimuth/2),  |j - cy| <= k tan(elevation/2),
// with cx = (size_x - 1)/2, cy = (size_y - 1)/2 (the spacing is isotropic, so the test in
// mm from the apex is the same in voxels).
//
// Poses (T_i = frame_from_world, world = the source's physical space, mm), always of the form
//   frame_from_world_i = Translate(c_f) * R_i * Translate(t_i - c_s)
// with c_f the frame grid's physical centre and c_s the source grid's physical centre: the
// frame centre sees the world point c_s - t_i and the frame is rotated about it. The pose
// box is R = Rz(gamma) Ry(beta) Rx(alpha) with each Euler angle in
// [-max_rotation_deg, +max_rotation_deg] and t in [-max_translation_voxels,
// +max_translation_voxels] * s per world axis. Consumers re-express poses relative to
// frame 0 (docs/design.md section 1: world = frame 0). Every draw below is u, uniform in [-1, 1),
// from one std::mt19937_64(seed); after all poses come the noise draws of frame 0, 1, ...
// in voxel order (the ultrasound-like effects below draw from generators of their own).
//
// PoseModel::kRandom (the paper's protocol): every frame, frame 0 included, independently
// uniform in the box: per frame alpha, beta, gamma, t_x, t_y, t_z (= max * u each).
//
// PoseModel::kWalk (a probe tilted and shifted between acquisitions): frame 0 exactly as
// kRandom (so both models share frame 0 for one seed); each next frame is the previous one
// moved by a step applied in the world:
//   world_from_frame_i = Translate(d) * RotateAbout(p, Q) * world_from_frame_{i-1},
// where p = world_from_frame_{i-1} * c_f is the previous frame's centre in the world, Q a
// rotation by theta in [0, step_rotation_deg] about a world axis a, and d a world
// translation of length in [0, step_translation_voxels] * s. So the frame centre moves by d
// exactly and the relative rotation of consecutive frames is Q: in the parametrisation
// above, R_i = R_{i-1} Q^T and t_i = t_{i-1} - d. Draws per frame i >= 1: a_z = u,
// a_azimuth = pi u (a = (sqrt(1 - a_z^2) cos, sqrt(1 - a_z^2) sin, a_z): uniform on the
// sphere), theta = step (1 + u) / 2, then the direction of d likewise (z, azimuth) and its
// length = step (1 + u) / 2: six draws per frame, as for kRandom.
// The walk is clamped to the pose box, so it fits every source the box fits: each
// component of t_i is clamped to the box (which only shortens d), and where R_i would
// leave the Euler-angle box, theta is reduced (bisection on [0, theta], deterministic) to
// the largest angle that keeps it inside. The step bounds therefore always hold, the box
// bounds the whole sequence, and a frame stuck at a box face simply moves less.
//
// Intensities: the source's value at world_from_frame * x, plus N(0, sigma), clamped
// to 0..255, for field-of-view voxels; 0 outside (with the optional ultrasound-like effects
// below applied before the noise). The value is, by `interpolation`:
// kLinear (default) the trilinear value (Frame::InterpolateValue on an all-ones mask);
// kCubic Keys' cubic convolution (CubicInterpolateValue below). Simulate fails if a
// field-of-view voxel maps outside the source grid (the same test for both: the cubic
// stencil clamps its indices to the grid, see CubicInterpolateValue).
// Either way a noise-free frame holds exact point samples (up to float rounding) of one
// continuous function of the world: the source's trilinear or cubic interpolant clamped to
// 0..255 (the clamp only bites on kCubic's overshoot next to strong edges).
//
// Ultrasound-like effects (docs/design.md section 6.6), all off by default, so that a
// sequence without them is bit for bit the one the simulator made before they existed. Per
// field-of-view voxel of frame i, with S the interpolated source value:
//   I = clamp(g_i (S a(r) s_i) + o_i + N(0, sigma), 0, 255),
// where
//   a(r) = 10^(-attenuation_db_per_cm r / 20): depth attenuation, r the distance (cm) of the
//          voxel centre from the pyramid's apex (the centre of the k = 0 face, as above);
//   s_i  = speckle: the mean over speckle_looks looks of |z|^2 / E|z|^2, each z a white
//          circular complex Gaussian field on the frame grid (drawn on a grid padded by the
//          kernel radius, so every voxel sees the whole kernel) convolved with a Gaussian of
//          speckle_correlation_voxels voxels' standard deviation (c). Mean 1, variance 1/L
//          (a gamma distribution with L looks), intensity autocorrelation
//          |sum_t w_t w_t+d|^2 at a lag of d voxels along an axis (w the 1-D kernel, unit
//          squared sum), which is exp(-d^2 / (2 c^2)) to 1e-3 for c >= 1. Drawn per frame
//          on the frame grid, it follows the probe, not the tissue, unless
//          speckle_world_fraction rho > 0 (SpeckleFields): then each look's complex field is
//            z_l(x) = sqrt(rho) zW_l(world_from_frame_i x) + sqrt(1 - rho) z_i,l(x),
//          z_i,l the per-frame field above (the same draws) and zW_l one world-fixed field per
//          look, shared by all frames (scatterers fixed in the tissue), so at one world
//          point two frames' speckle intensities correlate by about rho^2;
//   g_i  = 1 + gain_range u, o_i = offset_range u' (u, u' uniform in [-1, 1)): the frame's
//          gain and offset (SimulatedSequence::gain/offset).
// Outside the field of view the voxels stay 0. The effects' draws come from their own
// generators, std::mt19937_64 seeded by a 64-bit mix of (seed, a constant per effect,
// frame index[, look, padded slice]; the world speckle: look, padded slice of the world
// grid), never from the poses-and-noise generator, so the poses and the noise draws are the
// same with the effects on or off, and the speckle does not depend on the thread count.
//
// Intensity mapping (docs/design.md section 6.6), kNone by default (the source as it is,
// bit for bit the simulator before the option). IntensityMapping::kEcho makes any source
// look like echocardiography (sim/echo_mapping.h): the source is mapped once, on its own
// grid, before any frame is cut,
//   E = 255 clamp((1 - w) max(0, S - r) / (255 - r) + w min(1, |grad G_sigma * S| / g99), 0, 1)
// (r = echo_reject: a dark blood pool, lungs or CSF go black; w = echo_edge_weight and
// sigma = echo_edge_sigma_mm: bright interfaces), and the frames sample E instead of S; the
// poses, the effects and the noise are drawn and applied exactly as without it.
//
// Beating source (ECG-gated loops), off with num_phases = 1 (the default: every sequence
// bit for bit the simulator's before the option). Each view i is recorded over T =
// num_phases phases p = 0 .. T - 1 of one heart cycle, at cycle fraction t = p / T; the probe
// does not move during a loop, so all phases of a view share its pose, field of view and
// mask. Phase p samples the source at the pull-back
//   psi_p(x) = x - d_p(x),  i.e.  S_p(x) = S(x - d_p(x))   (world points x, mm),
// d_p the Eulerian displacement: the tissue seen at x in phase p is the tissue at x - d_p(x)
// in phase 0. No inversion is approximated: psi_p is a diffeomorphism (identity outside the
// region, Jacobian determinant > 0 inside, BeatPullbackJacobian), so the tissue moves by its
// inverse. The field is a radial contraction towards the region's centre c (radius R):
//   d_p(x) = -A b(t) kappa (1 - rho^2)^3 (x - c) / R  for rho = |x - c| / R < 1, else 0,
//   b(t) = (1 - cos(2 pi t)) / 2,  kappa = sqrt(7) (7/6)^3
// (A = beat_amplitude_mm; kappa makes max |d| = A b(t), reached at rho = 1/sqrt(7)). It is a
// polynomial inside the ball, C^2 across its sphere (a triple zero) and exactly 0 outside
// it, periodic in t (b(1) = b(0) = 0: phase 0 is the undeformed source, phase T would be
// phase 0 again), largest at end-systole t = 1/2. In the radial direction the pull-back
// stretches by 1 + A b kappa (1 - rho^2)^2 (1 - 7 rho^2) / R >= 1 - (32/49) kappa A / R, so
// A <= kMaxBeatAmplitudeRatio R (checked) keeps every determinant above 0.3. The region:
// c = the source grid's physical centre (which every frame centre sees, up to its
// translation) + beat_center_offset_mm, R = beat_radius_mm or, at 0, a quarter of the frame
// depth (frame_size[2] s): for the default frames a 20 mm ball in the middle of every
// view, with still anatomy all around it.
// Noise with phases: phase 0 takes exactly the draws a still sequence takes (the
// poses-and-noise generator, speckle, gain and offset), so it is the still sequence bit for
// bit (with a world-fixed speckle part: when the region's ball lies inside the box of the
// fields of view, as it does for the defaults; else the world grid grows to hold it,
// SpeckleWorldGrid). Each later phase (view i, phase p >= 1) draws its own Gaussian noise from a
// generator of its own (seed, "phase_no", i, p; voxel order) and its own per-frame speckle part
// (seed, "speckleP", i, p, look, padded slice); the world-fixed speckle part (rho > 0) is the
// tissue's, so it moves with it: phase p samples the world field at psi_p(world point). The
// gain and offset of a view are shared by its phases. Cost per later phase and view: one
// frame's sampling (plus d_p per field-of-view voxel), its speckle looks and its noise, as a
// still frame's; with rho > 0 the world fields of every look are drawn again per phase
// (memory: as a still sequence's, one phase's speckle fields at a time). Memory: the output
// (T frames per view) plus one frame in the making.
//
// Masks: the field of view eroded by mask_erosion (default 1) voxels, each voxel of
// erosion a 6-neighbourhood erosion that also drops the grid border. 0 writes the exact
// field of view. The registration's gradients read mask voxels only whatever the mask
// (image/frame.h: a valid cell's corners need their 6 neighbours inside the mask), so for
// this project erosion only shrinks the data; 1 suits registrations that read one voxel
// past their mask.
#ifndef DSR_SIM_SIMULATE_H_
#define DSR_SIM_SIMULATE_H_

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "dsr/geometry/volume.h"

namespace dsr {

// How the frames' poses are drawn (see the header comment). dsr_simulate's --pose_model.
enum class PoseModel { kRandom, kWalk };

// "random" / "walk"; "" for a value outside the enum.
const char* PoseModelToString(PoseModel model);
// The inverse of PoseModelToString; false (and *model untouched) for any other text.
bool StringToPoseModel(const std::string& text, PoseModel* model);

// How a frame samples the source (see the header comment). dsr_simulate's --interpolation.
enum class SourceInterpolation { kLinear, kCubic };

// "linear" / "cubic"; "" for a value outside the enum.
const char* SourceInterpolationToString(SourceInterpolation interpolation);
// The inverse of SourceInterpolationToString; false (and *interpolation untouched) for any
// other text.
bool StringToSourceInterpolation(const std::string& text, SourceInterpolation* interpolation);

// How the source's intensities are mapped before the frames are cut (see the header
// comment). dsr_simulate's --intensity_mapping.
enum class IntensityMapping { kNone, kEcho };

// "none" / "echo"; "" for a value outside the enum.
const char* IntensityMappingToString(IntensityMapping mapping);
// The inverse of IntensityMappingToString; false (and *mapping untouched) for any other text.
bool StringToIntensityMapping(const std::string& text, IntensityMapping* mapping);

// Keys' cubic convolution (a = -0.5, no prefilter) of `image` at the continuous index
// `ijk`: the separable sum over the 4x4x4 voxels floor(ijk) - 1 .. floor(ijk) + 2 with
// per-axis weights, for t = ijk[a] - floor(ijk[a]) in [0, 1),
//   w_-1 = (-t^3 + 2t^2 - t)/2,  w_0 = (3t^3 - 5t^2 + 2)/2,
//   w_+1 = (-3t^3 + 4t^2 + t)/2, w_+2 = (t^3 - t^2)/2.
// It interpolates (the voxel's value at integer ijk) and reproduces every polynomial of
// degree <= 2 exactly where the stencil lies inside the grid. Stencil indices outside the
// grid are clamped to its border (the border voxel repeated), so any ijk in
// [0, size - 1] per axis is defined. ijk must be finite; image must be non-empty.
double CubicInterpolateValue(const Image& image, const Eigen::Vector3d& ijk);

struct SimulationOptions {
  int num_frames = 11;                   // >= 2 (the paper: 11)
  PoseModel pose_model = PoseModel::kRandom;
  double max_rotation_deg = 12.0;        // per Euler angle, in [0, 180]
  double max_translation_voxels = 15.0;  // per world axis, in frame voxels, >= 0
  double step_rotation_deg = 6.0;        // kWalk: largest rotation per step, in [0, 180]
  double step_translation_voxels = 6.0;  // kWalk: largest shift per step, frame voxels, >= 0
  double sigma = 25.0;             // intensity units, >= 0
  uint64_t seed = 1;
  Eigen::Vector3i frame_size = Eigen::Vector3i(96, 96, 80);  // voxels, depth along k
  double frame_spacing = 0.0;  // 0: the source's spacing along its first axis
  double azimuth_deg = 75.0;      // full opening angles of the pyramid, in (0, 180)
  double elevation_deg = 75.0;
  double min_depth_voxels = 4.0;  // near-field cut, in [0, frame_size[2] - 3]
  int mask_erosion = 1;    // erosion of the written masks, in [0, 50]; 0 = the FOV
  SourceInterpolation interpolation = SourceInterpolation::kLinear;  // how frames sample
  // Ultrasound-like effects (see the header comment); each default leaves them off.
  double gain_range = 0.0;    // per-frame gain uniform in [1 - this, 1 + this], in [0, 0.9]
  double offset_range = 0.0;  // per-frame offset uniform in [-this, this], grey levels, [0, 100]
  int speckle_looks = 0;      // 0: no speckle; else looks L averaged, in [1, 64]
  // Standard deviation (frame voxels) of the Gaussian that correlates each look's complex
  // field, in [0, 4]; 0: independent voxels.
  double speckle_correlation_voxels = 1.0;
  // Fraction rho of each look's complex speckle field that is fixed in the world (the
  // tissue) rather than drawn per frame, in [0, 1]; > 0 needs speckle_looks >= 1. 0: every
  // frame's speckle is its own (bit for bit the simulator before this option).
  double speckle_world_fraction = 0.0;
  double attenuation_db_per_cm = 0.0;  // depth attenuation from the apex, dB/cm, in [0, 10]
  // Echo-like mapping of the source (see the header comment and sim/echo_mapping.h); the
  // three echo_ parameters are used only with kEcho.
  IntensityMapping intensity_mapping = IntensityMapping::kNone;
  // Source values up to this go black (an echo machine's reject), grey levels, in [0, 250];
  // 0.3 x full scale: blood, lungs, fat and CSF in the project's sources.
  double echo_reject = 0.3 * 255.0;
  // Standard deviation (mm, physical: sources may be anisotropic) of the Gaussian smoothing
  // the source before its gradient is taken, in [0, 20]; 0: the raw source's gradient.
  double echo_edge_sigma_mm = 1.0;
  // Share w of the full scale that the interfaces (gradient magnitude at or above its 99th
  // percentile) add, in [0, 1]; 0: no edge term.
  double echo_edge_weight = 0.35;
  // Real-echo artefacts (sim/echo_artifacts.h, docs/design.md 6.7); each off at 0.
  // e: interfaces across the beam brighter by up to this share, along it darker, in [0, 0.9].
  double echogenicity_range = 0.0;
  // s: the share of the beam a voxel at full scale stops (acoustic shadows behind bright
  // reflectors), in [0, 1]; shadow_threshold r: values above it cast shadows, in [0, 250].
  double shadow_strength = 0.0;
  double shadow_threshold = 200.0;
  // Lateral point-spread function: the Gaussian's standard deviation (mm) across the beam at
  // the frame's full depth, growing linearly from 0 at the apex, in [0, 20].
  double psf_lateral_mm = 0.0;
  // Dropouts: the largest share f of the sector's azimuth opening a view's wedge of lost
  // signal covers, in [0, 0.9]; dropout_view_fraction q: the chance a view has one, [0, 1].
  double dropout_fraction = 0.0;
  double dropout_view_fraction = 0.33;
  // The masks leave out each view's dropout wedge: the simulator's own knowledge of where
  // the signal is lost, to compare a registration's detection with.
  bool dropouts_out_of_masks = false;
  // Beating source (see the header comment); the beat_ parameters are used only with
  // num_phases >= 2.
  int num_phases = 1;  // T phases of the heart cycle per view, in [1, 64]; 1: a still source
  // A: the largest displacement (end-systole), mm, in [0, 50]; 0: still anatomy in every
  // phase. At most kMaxBeatAmplitudeRatio R.
  double beat_amplitude_mm = 4.0;
  // R: the moving region's radius, mm, 0 or in [1e-3, 1e6]; 0: a quarter of the frame depth.
  double beat_radius_mm = 0.0;
  // The region's centre minus the source grid's physical centre, mm, finite.
  Eigen::Vector3d beat_center_offset_mm = Eigen::Vector3d::Zero();

  // Checks ranges and cross-field rules. The message names the field
  // (util/option_fields.h; e.g. "num_frames=1: must be in [2, 1000]").
  bool Validate(std::string* error) const;
};

// A <= this R: the beat folds no tissue (see the header comment).
constexpr double kMaxBeatAmplitudeRatio = 0.25;

struct SimulatedSequence {
  // View i at phase 0 (with num_phases = 1: the only phase); on the frame grid, 0..255, 0
  // outside the FOV.
  std::vector<Image> frames;
  // The later phases: later_phases[i][p - 1] = view i at phase p, p in [1, num_phases)
  // (one vector per view, empty with num_phases = 1). Phase(i, p) reads either.
  std::vector<std::vector<Image>> later_phases;
  std::vector<Mask> masks;    // the field of view eroded by mask_erosion (all equal)
  std::vector<Eigen::Isometry3d> frame_from_world;  // world = the source's physical space
  // The frames' drawn gains g_i and offsets o_i (frame i = g_i S + o_i before noise, S the
  // source, attenuated and speckled); 1 and 0 when gain_range and offset_range are 0. For
  // the registration's convention see Frame0IntensityCorrections.
  std::vector<double> gain;
  std::vector<double> offset;

  // The phases per view (1 + later_phases[0].size(); 1 without later phases).
  int num_phases() const {
    return later_phases.empty() ? 1 : 1 + static_cast<int>(later_phases[0].size());
  }
  // View `view` at phase `phase` (in [0, num_phases())).
  const Image& Phase(int view, int phase) const {
    return phase == 0 ? frames.at(view) : later_phases.at(view).at(phase - 1);
  }
};

// The beating region (see the header comment) in the world (the source's physical space).
struct BeatRegion {
  Eigen::Vector3d center_mm = Eigen::Vector3d::Zero();  // c
  double radius_mm = 1.0;                               // R > 0
  double amplitude_mm = 0.0;                            // A >= 0
};

// The region Simulate uses for `source` (options valid): c = the grid's physical centre +
// beat_center_offset_mm, R = beat_radius_mm or a quarter of the frame depth, A =
// beat_amplitude_mm.
BeatRegion SimulatedBeatRegion(const ImageGeometry& source, const SimulationOptions& options);

// The cycle fraction's weight b(t) = (1 - cos(2 pi t)) / 2.
double BeatCycleWeight(double t);

// d(x) at cycle fraction t (phase p of T: t = p / T), see the header comment; exactly 0
// outside the region's open ball and at t = 0.
Eigen::Vector3d BeatDisplacement(const BeatRegion& region, double t, const Eigen::Vector3d& x_mm);

// The Jacobian of the pull-back psi(x) = x - d(x) at cycle fraction t (analytic):
//   I + beta (q I - 6 (1 - rho^2)^2 (x - c)(x - c)^T / R^2),  q = (1 - rho^2)^3,
// beta = A b(t) kappa / R, inside the ball; I outside.
Eigen::Matrix3d BeatPullbackJacobian(const BeatRegion& region, double t,
                                     const Eigen::Vector3d& x_mm);

// The frame grid for `source` (see the header comment). options must be valid.
ImageGeometry SimulatedFrameGeometry(const ImageGeometry& source, const SimulationOptions& options);

// The pyramidal field of view on `frame` (before erosion), 1 inside.
Mask PyramidFieldOfView(const ImageGeometry& frame, const SimulationOptions& options);

// The mask written with each frame: `field_of_view` eroded `erosion_voxels` (>= 0) times
// by one voxel (6-neighbourhood, grid-border voxels removed each time); 0 returns it as is.
Mask ErodeFieldOfView(const Mask& field_of_view, int erosion_voxels);

// The ground-truth poses Simulate draws for `source` (the same first draws of the seeded
// generator). options must be valid.
std::vector<Eigen::Isometry3d> SimulatedPoses(const ImageGeometry& source,
                                              const SimulationOptions& options);

// The intensity corrections a registration estimates, from the drawn `gain` g_i and
// `offset` o_i (SimulatedSequence): frame i's corrected observation
// corrected_gain_i I_i + corrected_offset_i is on frame 0's intensity scale, so with
// I_i = g_i S + o_i,
//   corrected_gain_i = g_0 / g_i,  corrected_offset_i = o_0 - g_0 o_i / g_i,
// and frame 0 (the gauge) gets exactly 1 and 0. Sizes must match, gains must be > 0.
void Frame0IntensityCorrections(const std::vector<double>& gain,
                                const std::vector<double>& offset,
                                std::vector<double>* corrected_gain,
                                std::vector<double>* corrected_offset);

// Frame `frame_index`'s multiplicative speckle on `frame` (the frame grid, see the header
// comment): mean 1, variance 1 / speckle_looks, correlated over about
// speckle_correlation_voxels. Bit-identical for every num_threads (<= 0: all hardware
// threads). options must be valid with speckle_looks >= 1 and speckle_world_fraction 0
// (a world-fixed part depends on every frame's pose: SpeckleFields).
// Phase `phase` >= 1 of a beating sequence draws the per-frame field from a stream of its
// own (see the header comment), phase 0 the still frame's.
Image SpeckleField(const ImageGeometry& frame,
                   const SimulationOptions& options,
                   int frame_index,
                   int num_threads,
                   int phase = 0);

// The axis-aligned world grid that carries the world-fixed speckle of the frames at
// `frame_from_world` (frame i at frame_from_world[i], all on the grid `frame`, whose
// spacing must be isotropic): identity direction, the frames' spacing s, the lattice of
// world points n s (n integer), and the smallest such box that holds every frame's
// field-of-view voxel centres (PyramidFieldOfView of `frame`), so that trilinear sampling
// inside the fields of view never leaves it. options must be valid; frame_from_world
// non-empty. With a `beat` (a beating sequence's later phases sample the world field at
// psi_p of the field-of-view points, which stay in the region's ball or are not moved) the
// box also holds the ball's box; the grid is the same as without it when it already did.
ImageGeometry SpeckleWorldGrid(const ImageGeometry& frame,
                               const std::vector<Eigen::Isometry3d>& frame_from_world,
                               const SimulationOptions& options,
                               const BeatRegion* beat = nullptr);

// Every frame's multiplicative speckle (frame i at frame_from_world[i], on the grid
// `frame`), as Simulate applies it. With speckle_world_fraction rho = 0 frame i's field is
// exactly SpeckleField(frame, options, i, ...). With rho > 0, per look l and frame voxel x
// of frame i, the complex field is
//   z_l(x) = sqrt(rho) zW_l(p) / sqrt(V(p)) + sqrt(1 - rho) z_i,l(x),
//   p = world_from_frame_i x, as an index of SpeckleWorldGrid,
// with z_i,l SpeckleField's per-frame field (the same draws) and zW_l the trilinear
// interpolant of one white circular complex Gaussian field per look, drawn on the world
// grid padded by the kernel radius and smoothed with SpeckleField's separable kernel w
// (c in world voxels = frame voxels). The smoothed field's correlation is separable, with
// r1 = sum_d w_d w_d+1 at one grid step along an axis, so trilinear weights (1 - t, t)
// give the interpolant the variance factor
//   V(p) = prod over the 3 axes of ((1 - t)^2 + t^2 + 2 t (1 - t) r1)
// exactly (c = 0: r1 = 0); dividing by its root keeps z_l circular complex Gaussian with
// today's E|z_l|^2 at every voxel. So the speckle s = mean over looks of |z_l|^2 / E|z|^2
// still has mean 1 and variance 1 / speckle_looks, and two frames' s at one world point
// correlate by rho^2 (the intensity correlation of a complex correlation rho). With rho > 0
// the fields are 1 outside the field of view (PyramidFieldOfView of `frame`), where
// Simulate writes 0 anyway: sampling the world field is most of the cost. The world field
// depends on the grid, i.e. on all the poses passed. Memory: one look's world field
// (16 bytes per padded world voxel) at a time, plus the returned fields.
// Bit-identical for every num_threads (<= 0: all hardware threads). options must be valid
// with speckle_looks >= 1; frame_from_world non-empty.
// Phase `phase` >= 1 of a beating sequence (`beat` non-null, options.num_phases > phase):
// the per-frame parts are SpeckleField's of that phase, and the world part is sampled at
// psi_p(p) (the tissue moves, its scatterers with it) on SpeckleWorldGrid(..., beat); phase
// 0 with a beat: the world grid with the ball, otherwise as without. Each call draws every
// look's world field again.
std::vector<Image> SpeckleFields(const ImageGeometry& frame,
                                 const std::vector<Eigen::Isometry3d>& frame_from_world,
                                 const SimulationOptions& options,
                                 int num_threads,
                                 int phase = 0,
                                 const BeatRegion* beat = nullptr);

// Runs the protocol. Returns false with a one-line `error` when options are invalid, the
// source is empty or has an invalid grid, the (eroded) mask is empty, or a
// field-of-view voxel of some frame maps outside the source grid (source too small for
// these poses and this frame size), also in a later phase of a beating sequence, or the
// beat would fold the tissue (beat_amplitude_mm > kMaxBeatAmplitudeRatio R once R is
// known). `sequence` is only written on success.
bool Simulate(const Image& source,
              const SimulationOptions& options,
              SimulatedSequence* sequence,
              std::string* error);

}  // namespace dsr

#endif  // DSR_SIM_SIMULATE_H_
