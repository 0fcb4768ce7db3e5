// Report pictures: each is written with the expected size and is not blank, and
// the report folder holds the pictures, poses, transforms and an index linking them.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "dsr/io/io_picture.h"
#include "dsr/io/io_transform.h"
#include "dsr/model/panorama.h"
#include "dsr/pipeline/registration.h"
#include "dsr/pipeline/report.h"
#include "dsr/sim/phantom.h"
#include "dsr/sim/simulate.h"
#include "dsr/tests/support/scoped_temp_dir.h"

namespace dsr {
namespace {

struct Registered {
  SimulatedSequence sequence;
  std::vector<Frame> frames;
  RegistrationResult result;
  Image panorama;
};

const Registered& Small() {
  static const Registered* r = [] {
    auto* out = new Registered;
    PhantomOptions phantom;
    phantom.size = 96;
    SimulationOptions options;
    options.num_frames = 3;
    options.frame_size = Eigen::Vector3i(40, 40, 32);
    options.max_translation_voxels = 3.0;
    options.max_rotation_deg = 6.0;
    options.min_depth_voxels = 2.0;
    options.sigma = 5.0;
    std::string error;
    EXPECT_TRUE(Simulate(MakePhantom(phantom), options, &out->sequence, &error)) << error;
    RegistrationOptions o;
    o.solve.progress = false;
    o.solve.num_threads = 2;
    o.pyramid_levels = 2;
    o.pyramid_min_size = 8;
    const std::vector<Eigen::Isometry3d> identity(3, Eigen::Isometry3d::Identity());
    EXPECT_TRUE(
        Register(out->sequence.frames, out->sequence.masks, identity, o, &out->result, &error))
        << error;
    for (int i = 0; i < 3; ++i)
      out->frames.emplace_back(out->sequence.frames[i], out->sequence.masks[i]);
    out->panorama =
        FusePanoramaMean(out->frames, out->result.frame_from_world, out->result.grid, 2).mean;
    return out;
  }();
  return *r;
}

// Not blank: many distinct colours and a real spread of brightness.
void ExpectNotBlank(const Picture& p) {
  ASSERT_GT(p.width, 50);
  ASSERT_GT(p.height, 50);
  std::set<int> colours;
  double sum = 0.0, sum2 = 0.0;
  const size_t n = size_t(p.width) * p.height;
  for (size_t i = 0; i < n; ++i) {
    const int c = p.rgb[3 * i] << 16 | p.rgb[3 * i + 1] << 8 | p.rgb[3 * i + 2];
    colours.insert(c);
    const double g = (p.rgb[3 * i] + p.rgb[3 * i + 1] + p.rgb[3 * i + 2]) / 3.0;
    sum += g;
    sum2 += g * g;
  }
  EXPECT_GT(colours.size(), 20u);
  EXPECT_GT(std::sqrt(sum2 / n - (sum / n) * (sum / n)), 10.0);
}

TEST(Report, PicturesHaveTheExpectedSizeAndContent) {
  const Registered& r = Small();
  const ImageGeometry& g = r.panorama.geometry;
  const Picture slices =
      RenderPanoramaSlices(r.panorama, r.frames, r.result.frame_from_world, {0, 2});
  const int scale = std::max(1, 320 / std::max({g.size[0], g.size[1], g.size[2]}));
  // Three slices side by side: (x,y), (x,z), (y,z) at `scale` pixels per voxel, 10-pixel gaps.
  EXPECT_EQ(slices.width, scale * (2 * g.size[0] + g.size[1]) + 3 * 10 + 10);
  EXPECT_GE(slices.height, scale * std::max(g.size[1], g.size[2]) + 30);
  ExpectNotBlank(slices);
  // Frame outlines in their colours (frame 0 red, frame 2 yellow in the palette).
  bool red = false, yellow = false;
  for (int y = 0; y < slices.height; ++y) {
    for (int x = 0; x < slices.width; ++x) {
      const Rgb c = slices.Get(x, y);
      red |= c == Rgb{230, 25, 75};
      yellow |= c == Rgb{255, 225, 25};
    }
  }
  EXPECT_TRUE(red);
  EXPECT_TRUE(yellow);

  const std::vector<Eigen::Isometry3d> identity(3, Eigen::Isometry3d::Identity());
  const Picture pair =
      RenderPairComparison(r.frames, 0, 1, identity, r.result.frame_from_world, r.result.grid);
  const int pscale = std::max(1, 280 / std::max(g.size[0], g.size[1]));
  EXPECT_EQ(pair.width, 2 * g.size[0] * pscale + 30);
  EXPECT_EQ(pair.height, 2 * g.size[1] * pscale + 60);
  ExpectNotBlank(pair);

  const Picture convergence = RenderConvergence(r.result.solves);
  EXPECT_EQ(convergence.width, 1440);
  EXPECT_EQ(convergence.height, 300);
  ExpectNotBlank(convergence);
}

TEST(Report, FolderHoldsPicturesPosesTransformsAndIndex) {
  const Registered& r = Small();
  const ScopedTempDir temp("dsr_report_test");
  const std::string& dir = temp.path();
  ReportInputs in;
  in.image_names = {"a.nii.gz", "b.nii.gz", "c.nii.gz"};
  in.frames = r.frames;
  in.initial = std::vector<Eigen::Isometry3d>(3, Eigen::Isometry3d::Identity());
  in.result = &r.result;
  in.panorama = r.panorama;
  in.outlined = {0, 1, 2};
  in.pair_a = 1;
  in.pair_b = 2;
  in.mode = "dsr";
  std::string index, error;
  ASSERT_TRUE(WriteReport(dir, in, &index, &error)) << error;
  std::ifstream f(index);
  std::stringstream text;
  text << f.rdbuf();
  for (const char* name : {"panorama_slices.png", "pair_01_02.png", "convergence.png"}) {
    EXPECT_THAT(text.str(), ::testing::HasSubstr(name));
    Picture p;
    ASSERT_TRUE(ReadPng(dir + "/" + name, &p, &error)) << error;
    ExpectNotBlank(p);
  }
  EXPECT_THAT(text.str(), ::testing::HasSubstr("| 2 | c.nii.gz |"));
  Eigen::Affine3d t;
  ASSERT_TRUE(ReadItkTransform(dir + "/transforms/frame_02.tfm", &t, &error)) << error;
  EXPECT_LT((t.matrix() - r.result.frame_from_world[2].matrix()).norm(), 1e-12);
  EXPECT_TRUE(std::filesystem::exists(dir + "/poses.json"));
}

}  // namespace
}  // namespace dsr
