// The run config's audio: section (issue 7) and the temple relief synthetic surface.

#include "hc/pipeline/config.hpp"
#include "hc/pipeline/synthetic.hpp"

#include "hc/common/error.hpp"
#include "config_error.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

namespace {

using hc::pipeline::parse_run_config;
using hc::test::config_error;

const std::string kInput = "input:\n  files: [scan.ply]\n";

TEST(ConfigAudio, AbsentSectionMeansNoAudio) {
  const auto c = parse_run_config(kInput, "configs/test.yaml");
  EXPECT_FALSE(c.audio.has_value());
}

TEST(ConfigAudio, RegionsOfEveryShapeWithClipsNotesAndMaterials) {
  const std::string yaml = kInput +
                           "audio:\n"
                           "  master_gain: 0.4\n"
                           "  limiter: {threshold_dbfs: -3}\n"
                           "  force: {full_force_n: 2.5, strike_window_s: 0.02}\n"
                           "  slide: {material: {preset: bronze, q: 12}}\n"
                           "  label_image: labels.pgm\n"
                           "  regions:\n"
                           "    - {name: a, box_m: [0, 0, 0.01, 0.02], note: Dha, gain: 2}\n"
                           "    - name: b\n"
                           "      polygon_m: [[0, 0], [0.01, 0], [0, 0.01]]\n"
                           "      clip: sounds/b.flac\n"
                           "      pitch: 0.5\n"
                           "      mode: continuous\n"
                           "      retrigger: false\n"
                           "      material: wood\n"
                           "    - {name: c, label: 3, material: {preset: marble, slide_gain: 0.5}}\n";
  const auto c = parse_run_config(yaml, "configs/test.yaml");
  ASSERT_TRUE(c.audio.has_value());
  const hc::audio::AudioConfig& a = *c.audio;
  EXPECT_DOUBLE_EQ(a.master_gain, 0.4);
  EXPECT_DOUBLE_EQ(a.limiter_threshold, std::pow(10.0, -3.0 / 20.0));  // -3 dBFS, linear
  EXPECT_DOUBLE_EQ(a.force.full_force_n, 2.5);
  EXPECT_DOUBLE_EQ(a.force.strike_window_s, 0.02);
  EXPECT_DOUBLE_EQ(a.force.min_gain, 0.1);  // default
  EXPECT_EQ(a.default_material.name, "bronze");
  EXPECT_DOUBLE_EQ(a.default_material.q, 12.0);
  EXPECT_DOUBLE_EQ(a.default_material.resonance_hz, hc::audio::material_preset("bronze").resonance_hz);  // the preset's
  EXPECT_EQ(a.label_image, std::filesystem::path("configs/labels.pgm"));
  ASSERT_EQ(a.regions.size(), 3u);
  EXPECT_EQ(a.regions[0].shape.kind, hc::audio::ShapeKind::kBox);
  EXPECT_DOUBLE_EQ(a.regions[0].shape.y_max_m, 0.02);
  EXPECT_EQ(a.regions[0].note, hc::audio::Note::kDha);
  EXPECT_DOUBLE_EQ(a.regions[0].gain, 2.0);
  EXPECT_TRUE(a.regions[0].clip.empty());
  EXPECT_EQ(a.regions[1].shape.kind, hc::audio::ShapeKind::kPolygon);
  ASSERT_EQ(a.regions[1].shape.polygon_m.size(), 3u);
  EXPECT_DOUBLE_EQ(a.regions[1].shape.polygon_m[1][0], 0.01);
  EXPECT_EQ(a.regions[1].clip, std::filesystem::path("configs/sounds/b.flac"));
  EXPECT_EQ(a.regions[1].mode, hc::audio::PlayMode::kContinuous);
  EXPECT_FALSE(a.regions[1].retrigger);
  EXPECT_TRUE(a.regions[1].trigger_on_enter);
  EXPECT_EQ(a.regions[1].material.name, "wood");
  EXPECT_EQ(a.regions[2].shape.kind, hc::audio::ShapeKind::kLabel);
  EXPECT_EQ(a.regions[2].shape.label, 3);
  EXPECT_DOUBLE_EQ(a.regions[2].material.slide_gain, 0.5);
  EXPECT_NE(c.resolved_yaml.find("master_gain: 0.4"), std::string::npos) << c.resolved_yaml;
}

TEST(ConfigAudio, ErrorsNameTheKeyTheValueAndTheLine) {
  EXPECT_NE(config_error(kInput + "audio:\n  master_gain: 9\n").find("audio.master_gain = 9"), std::string::npos);
  const std::string unknown = config_error(kInput + "audio:\n  volume: 1\n");
  EXPECT_NE(unknown.find("unknown key 'audio.volume'"), std::string::npos) << unknown;
  const std::string note = config_error(kInput + "audio:\n  regions:\n    - {name: a, box_m: [0, 0, 1, 1], note: Do}\n");
  EXPECT_NE(note.find("audio.regions[0].note = 'Do'"), std::string::npos) << note;
  EXPECT_NE(note.find("configs/test.yaml:5"), std::string::npos) << note;
  const std::string shape = config_error(kInput + "audio:\n  regions:\n    - {name: a}\n");
  EXPECT_NE(shape.find("exactly one of box_m, polygon_m, label"), std::string::npos) << shape;
  const std::string box = config_error(kInput + "audio:\n  regions:\n    - {name: a, box_m: [1, 0, 0, 1]}\n");
  EXPECT_NE(box.find("x_max > x_min"), std::string::npos) << box;
  const std::string dup = config_error(kInput + "audio:\n  regions:\n    - {name: a, box_m: [0, 0, 1, 1]}\n"
                                            "    - {name: a, box_m: [0, 0, 1, 1]}\n");
  EXPECT_NE(dup.find("'a' twice"), std::string::npos) << dup;
  const std::string key = config_error(kInput + "audio:\n  regions:\n    - {name: a, box_m: [0, 0, 1, 1], loud: 3}\n");
  EXPECT_NE(key.find("unknown key 'loud'"), std::string::npos) << key;
  const std::string label = config_error(kInput + "audio:\n  regions:\n    - {name: a, label: 2}\n");
  EXPECT_NE(label.find("label_image"), std::string::npos) << label;
  const std::string mat = config_error(kInput + "audio:\n  slide: {material: glass}\n");
  EXPECT_NE(mat.find("audio.slide.material = 'glass'"), std::string::npos) << mat;
}

TEST(SyntheticTemple, SevenPillarsStandOutOfTheWallInsideTheirBoxes) {
  hc::pipeline::SyntheticSpec s;
  s.kind = hc::pipeline::surface_kind_from_string("temple_relief");
  EXPECT_EQ(hc::pipeline::to_string(s.kind), "temple_relief");
  s.half_extent_m = 0.05;
  s.amplitude_m = 0.002;
  const auto boxes = hc::pipeline::temple_pillar_boxes(s);
  ASSERT_EQ(boxes.size(), 7u);
  for (const auto& b : boxes) {
    const double cx = 0.5 * (b[0] + b[2]);
    EXPECT_NEAR(hc::pipeline::synthetic_height(s, cx, 0.005), 0.002 * 1.04, 1e-12);  // crest (+4 % flute)
    EXPECT_NEAR(hc::pipeline::synthetic_height(s, b[0] - 1e-4, 0.005), 0.0, 1e-6);  // wall just outside
    EXPECT_LT(hc::pipeline::synthetic_height(s, b[0] + 1e-3, 0.005), 0.002);          // rising flank
  }
  for (std::size_t i = 1; i < boxes.size(); ++i) EXPECT_GT(boxes[i][0], boxes[i - 1][2]);  // disjoint, in x order
  EXPECT_NEAR(hc::pipeline::synthetic_height(s, 0.0, 0.0475), 0.0, 1e-12);  // beyond the taper: wall
}

}  // namespace
