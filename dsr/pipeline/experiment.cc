#include "dsr/pipeline/experiment.h"

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <sstream>

#include "dsr/eval/eval.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/registration_result.h"
#include "dsr/util/clock.h"

namespace dsr {
namespace {

// A double for the pipe: "nan" for NaN (which operator>> cannot read back).
std::string Number(double value) {
  if (std::isnan(value)) return "nan";
  std::ostringstream s;
  s.precision(17);
  s << value;
  return s.str();
}

// The child's answer on the pipe: the row's numbers and poses, whitespace-separated.
std::string Serialize(const ComparisonRow& row) {
  std::ostringstream s;
  s.precision(17);
  s << row.ok << ' ' << row.mae_translation_voxels << ' ' << row.mae_translation_mm << ' '
    << row.mae_rotation_rad << ' ' << row.tre_mean_mm << ' ' << row.tre_max_mm << ' '
    << row.shared_offset_mm[0] << ' ' << row.shared_offset_mm[1] << ' '
    << row.shared_offset_mm[2] << ' ' << row.frame_spread_mm << ' ' << row.iterations << ' '
    << row.recoveries << ' ' << row.seconds_per_iteration << ' '
    << row.differences_per_iteration << ' ' << row.seconds << ' ' << row.added_memory_mb << ' '
    << Number(row.predicted_tre_mm) << ' ' << Number(row.nees) << ' '
    << Number(row.mae_gain) << ' ' << Number(row.mae_offset) << ' '
    << Number(row.structure_fraction) << ' ' << Number(row.structure_significance) << ' '
    << Number(row.pose_error_voxels) << ' '
    << row.frame_from_world.size();
  for (const Eigen::Isometry3d& t : row.frame_from_world) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) s << ' ' << t(r, c);
  }
  s << ' ' << row.photometric.size();
  for (const Photometric& p : row.photometric) s << ' ' << p.log_gain << ' ' << p.offset;
  s << '\n' << row.failure;
  return s.str();
}

bool Deserialize(const std::string& text, ComparisonRow* row) {
  std::istringstream s(text);
  size_t poses = 0;
  s >> row->ok >> row->mae_translation_voxels >> row->mae_translation_mm >>
      row->mae_rotation_rad >> row->tre_mean_mm >> row->tre_max_mm >> row->shared_offset_mm[0] >>
      row->shared_offset_mm[1] >> row->shared_offset_mm[2] >> row->frame_spread_mm >>
      row->iterations >> row->recoveries >> row->seconds_per_iteration >>
      row->differences_per_iteration >> row->seconds >> row->added_memory_mb;
  std::string predicted, nees, mae_gain, mae_offset, structure, significance, pose_error;
  s >> predicted >> nees >> mae_gain >> mae_offset >> structure >> significance >> pose_error >>
      poses;
  if (!s || poses > 1000) return false;
  const auto number = [](const std::string& text) {
    return text == "nan" ? std::nan("") : std::stod(text);
  };
  row->predicted_tre_mm = number(predicted);
  row->nees = number(nees);
  row->mae_gain = number(mae_gain);
  row->mae_offset = number(mae_offset);
  row->structure_fraction = number(structure);
  row->structure_significance = number(significance);
  row->pose_error_voxels = number(pose_error);
  row->frame_from_world.assign(poses, Eigen::Isometry3d::Identity());
  for (Eigen::Isometry3d& t : row->frame_from_world) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) s >> t(r, c);
  }
  size_t photometric = 0;
  s >> photometric;
  if (!s || photometric > 1000) return false;
  row->photometric.assign(photometric, Photometric());
  for (Photometric& p : row->photometric) s >> p.log_gain >> p.offset;
  if (!s) return false;
  std::string rest;
  std::getline(s, rest);  // end of the numbers line
  std::getline(s, row->failure, '\0');
  return true;
}

// The checks' statistics of a registration, usable or not: its recoveries, the largest
// structure fraction a final check judged, and the largest predicted pose error.
void RecordChecks(const RegistrationResult& result, ComparisonRow* row) {
  row->recoveries = static_cast<int>(result.recoveries.size());
  for (const FrameStructure& f : result.frame_structure) {
    if (f.judged && !(f.fraction <= row->structure_fraction)) {
      row->structure_fraction = f.fraction;
      row->structure_significance = f.significance;
    }
  }
  if (!result.pose_error_voxels.empty()) {
    row->pose_error_voxels =
        *std::max_element(result.pose_error_voxels.begin(), result.pose_error_voxels.end());
  }
}

// A usable registration's errors against the ground truth, its poses and gains and offsets,
// and what its finest level's solves cost.
void RecordAccuracy(const ExperimentSequence& sequence,
                    const RegistrationResult& result,
                    ComparisonRow* row) {
  const PoseErrorSummary errors =
      ComparePoses(result.frame_from_world, sequence.ground_truth, sequence.masks);
  row->ok = true;
  row->mae_translation_voxels = errors.mae_translation_voxels;
  row->mae_translation_mm = errors.mae_translation_mm;
  row->mae_rotation_rad = errors.mae_rotation_rad;
  row->tre_mean_mm = errors.tre_mean_mm;
  row->tre_max_mm = errors.tre_max_mm;
  row->shared_offset_mm = errors.shared_offset_mm;
  row->frame_spread_mm = errors.frame_spread_mm;
  row->iterations = result.total_iterations;
  double finest_seconds = 0.0, finest_differences = 0.0;
  int finest_iterations = 0, finest_solves = 0;
  for (const LevelSolve& solve : result.solves) {
    if (solve.level != 0) continue;
    finest_seconds += solve.report.seconds;
    finest_iterations += solve.report.num_iterations;
    finest_differences += static_cast<double>(solve.report.observations_per_iteration);
    ++finest_solves;
  }
  row->seconds_per_iteration = finest_seconds / std::max(1, finest_iterations);
  row->differences_per_iteration = finest_differences / std::max(1, finest_solves);
  row->frame_from_world = result.frame_from_world;
  row->photometric = result.photometric;
}

// A usable registration's estimates besides the poses against the truth: the gains' and
// offsets' mean errors (where the truth has them) and the pose uncertainty's predicted TRE
// and normalised squared error (where it was estimated).
void RecordEstimates(const ExperimentSequence& sequence,
                     const RegistrationResult& result,
                     ComparisonRow* row) {
  const std::vector<Photometric>& truth = sequence.ground_truth_photometric;
  const size_t m = row->photometric.size();
  if (m > 1 && truth.size() == m) {
    double gain = 0.0, offset = 0.0;
    for (size_t i = 1; i < m; ++i) {
      gain += std::abs(row->photometric[i].gain() - truth[i].gain());
      offset += std::abs(row->photometric[i].offset - truth[i].offset);
    }
    row->mae_gain = gain / (m - 1);
    row->mae_offset = offset / (m - 1);
  }
  const PoseUncertainty& u = result.uncertainty;
  if (!u.covariance.empty()) {
    const std::vector<Eigen::Isometry3d> truth = RelativeToFrame0(sequence.ground_truth);
    const std::vector<Eigen::Isometry3d> estimate = RelativeToFrame0(result.frame_from_world);
    double predicted = 0.0, nees = 0.0;
    const int m = static_cast<int>(truth.size());
    for (int i = 1; i < m; ++i) {
      predicted += u.predicted_tre_mm[i];
      nees += NormalisedSquaredError(estimate[i], truth[i], u.covariance[i]);
    }
    row->predicted_tre_mm = predicted / (m - 1);
    row->nees = nees / (m - 1);
  }
}

ComparisonRow RunInProcess(const ExperimentSequence& sequence, const RegistrationOptions& options) {
  ComparisonRow row;
  // Memory at the start (in a child: what it shares with the parent), in MB; the parent
  // turns it into the run's added memory with the child's peak.
  row.added_memory_mb = CurrentResidentBytes() / 1048576.0;
  const auto start = std::chrono::steady_clock::now();
  const std::vector<Eigen::Isometry3d> identity(sequence.frames.size(),
                                                Eigen::Isometry3d::Identity());
  RegistrationResult result;
  std::string error;
  if (!Register(sequence.frames, sequence.masks, identity, options, &result, &error)) {
    row.failure = error;
    return row;
  }
  row.seconds = SecondsSince(start);
  RecordChecks(result, &row);
  if (!result.usable) {
    row.failure = result.failure;
    // The poses it ended at, where it has them: what a refusal would have returned.
    if (result.frame_from_world.size() == sequence.ground_truth.size()) {
      const PoseErrorSummary refused =
          ComparePoses(result.frame_from_world, sequence.ground_truth, sequence.masks);
      row.tre_mean_mm = refused.tre_mean_mm;
      row.tre_max_mm = refused.tre_max_mm;
    }
    return row;
  }
  RecordAccuracy(sequence, result, &row);
  RecordEstimates(sequence, result, &row);
  return row;
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 == 1 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string CsvField(const std::string& text) {
  if (text.find_first_of(",\"\n") == std::string::npos) return text;
  std::string out = "\"";
  for (char c : text) out += c == '"' ? std::string("\"\"") : std::string(1, c == '\n' ? ' ' : c);
  return out + "\"";
}

}  // namespace

ComparisonRow RunMethod(const ExperimentSequence& sequence, const RegistrationOptions& options) {
  ComparisonRow row;
  int fds[2];
  if (pipe(fds) != 0) {
    row = RunInProcess(sequence, options);  // no isolation available: run here
    row.added_memory_mb = 0.0;               // unknown without a process of its own
  } else {
    std::fflush(nullptr);
    const pid_t pid = fork();
    if (pid == 0) {
      close(fds[0]);
      const std::string text = Serialize(RunInProcess(sequence, options));
      size_t written = 0;
      while (written < text.size()) {
        const ssize_t n = write(fds[1], text.data() + written, text.size() - written);
        if (n <= 0) break;
        written += static_cast<size_t>(n);
      }
      close(fds[1]);
      _exit(written == text.size() ? 0 : 3);
    }
    close(fds[1]);
    std::string text;
    char buffer[65536];
    for (;;) {
      const ssize_t n = read(fds[0], buffer, sizeof(buffer));
      if (n > 0) {
        text.append(buffer, static_cast<size_t>(n));
      } else if (n == 0 || errno != EINTR) {
        break;
      }
    }
    close(fds[0]);
    int status = 0;
    struct rusage usage {};
    const pid_t waited = pid > 0 ? wait4(pid, &status, 0, &usage) : -1;
    if (pid < 0 || waited != pid) {
      row.failure = "could not run the method in a child process";
    } else if (WIFSIGNALED(status)) {
      row.failure = std::string("the run was killed by signal ") + strsignal(WTERMSIG(status));
    } else if (!Deserialize(text, &row)) {
      row.failure = "the run ended without a result (exit status " +
                    std::to_string(WEXITSTATUS(status)) + ")";
    }
    if (waited == pid) {
      row.peak_memory_mb = usage.ru_maxrss / 1024.0;  // kB on Linux
      row.added_memory_mb = std::max(0.0, row.peak_memory_mb - row.added_memory_mb);
    }
  }
  row.method = MethodLabel(options);
  row.sequence = sequence.name;
  return row;
}

std::string MethodLabel(const RegistrationOptions& options) {
  return std::string(ModeToString(options.mode)) +
         (options.init == InitialPoses::kPairwise ? "+pairwise_init"
          : options.init == InitialPoses::kGlobal ? "+global_init"
          : options.max_recoveries > 0            ? "+auto"
                                                  : "") +
         (options.photometric == PhotometricModel::kAffine ? "+affine" : "") +
         (options.intensity_transform == IntensityTransform::kNone
              ? ""
              : std::string("+") + IntensityTransformToString(options.intensity_transform)) +
         (options.panorama_sampling == PanoramaSampling::kHalfVoxel
              ? ""
              : std::string("+") + PanoramaSamplingToString(options.panorama_sampling)) +
         (ModeTakesGauge(options.mode) && options.gauge == Gauge::kFrame0 ? "+frame0_gauge" : "") +
         (options.loss.IsSquared() ? "" : std::string("+") + RobustLossKindName(options.loss.kind));
}

std::string ComparisonCsv(const std::vector<ComparisonRow>& rows) {
  std::ostringstream s;
  s.precision(9);
  s << "method,sequence,ok,mae_translation_voxels,mae_translation_mm,mae_rotation_rad,"
       "tre_mean_mm,tre_max_mm,iterations,seconds_per_iteration,"
       "intensity_differences_per_iteration,seconds,peak_memory_mb,added_memory_mb,"
       "predicted_tre_mm,nees,mae_gain,mae_offset,failure,recoveries,"
       "shared_offset_mm,shared_offset_x_mm,shared_offset_y_mm,shared_offset_z_mm,"
       "frame_spread_mm,structure_fraction,structure_significance,pose_error_voxels\n";
  for (const ComparisonRow& r : rows) {
    s << CsvField(r.method) << ',' << CsvField(r.sequence) << ',' << (r.ok ? 1 : 0) << ','
      << r.mae_translation_voxels << ',' << r.mae_translation_mm << ',' << r.mae_rotation_rad
      << ',' << r.tre_mean_mm << ',' << r.tre_max_mm << ',' << r.iterations << ','
      << r.seconds_per_iteration << ',' << r.differences_per_iteration << ',' << r.seconds
      << ',' << r.peak_memory_mb << ',' << r.added_memory_mb << ',';
    if (!std::isnan(r.predicted_tre_mm)) s << r.predicted_tre_mm;
    for (double v : {r.nees, r.mae_gain, r.mae_offset}) {
      s << ',';
      if (!std::isnan(v)) s << v;
    }
    s << ',' << CsvField(r.failure) << ',' << r.recoveries << ',' << r.shared_offset_mm.norm()
      << ',' << r.shared_offset_mm[0] << ',' << r.shared_offset_mm[1] << ','
      << r.shared_offset_mm[2] << ',' << r.frame_spread_mm << ',';
    if (!std::isnan(r.structure_fraction)) s << r.structure_fraction;
    s << ',';
    if (!std::isnan(r.structure_significance)) s << r.structure_significance;
    s << ',';
    if (!std::isnan(r.pose_error_voxels)) s << r.pose_error_voxels;
    s << '\n';
  }
  return s.str();
}

std::string ComparisonMarkdown(const std::vector<ComparisonRow>& rows) {
  std::vector<std::string> methods;
  std::map<std::string, std::vector<const ComparisonRow*>> by_method;
  for (const ComparisonRow& r : rows) {
    if (by_method.find(r.method) == by_method.end()) methods.push_back(r.method);
    by_method[r.method].push_back(&r);
  }
  std::ostringstream s;
  s << "| method | runs ok | MAE translation (voxels) | MAE rotation (rad) | TRE mean (mm) | "
       "iterations | time / iteration (s) | intensity differences / iteration | total (s) | "
       "peak memory (MB) | added memory (MB) |\n";
  s << "|---|---|---|---|---|---|---|---|---|---|---|\n";
  char line[512];
  for (const std::string& m : methods) {
    std::vector<double> t, r, tre, it, spi, dpi, sec, mem, added;
    int ok = 0;
    for (const ComparisonRow* row : by_method[m]) {
      if (!row->ok) continue;
      ++ok;
      t.push_back(row->mae_translation_voxels);
      r.push_back(row->mae_rotation_rad);
      tre.push_back(row->tre_mean_mm);
      it.push_back(row->iterations);
      spi.push_back(row->seconds_per_iteration);
      dpi.push_back(row->differences_per_iteration);
      sec.push_back(row->seconds);
      mem.push_back(row->peak_memory_mb);
      added.push_back(row->added_memory_mb);
    }
    std::snprintf(
        line, sizeof(line),
        "| %s | %d/%zu | %.4g | %.3g | %.4g | %.0f | %.4g | %.4g | %.3g | %.0f | %.0f |\n",
        m.c_str(), ok, by_method[m].size(), Median(t), Median(r), Median(tre), Median(it),
        Median(spi), Median(dpi), Median(sec), Median(mem), Median(added));
    s << line;
  }
  s << "\nMedians over sequences; time and intensity differences per iteration at the finest "
       "pyramid level; added memory: the run's peak minus what its process held when it "
       "started (the sequence, the libraries).\n";
  return s.str();
}

}  // namespace dsr
