// hc::viewer under Xvfb + Mesa llvmpipe: what is drawn, checked from pixel statistics.

#include "viewer_fixture.hpp"
#include "test_paths.hpp"

#include "hc/haptics/shared_state.hpp"
#include "hc/viewer/viewer.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <vector>

namespace hc {
namespace {

using viewer::DisplayScene;
using viewer::Image;
using viewer::RegionCommand;
using viewer::RegionCommandType;
using viewer::Viewer;

// --- stereo maths (no GL) -------------------------------------------------------------------

/// NDC x of the eye-space point (x, 0, −d) under a projection.
double ndc_x(const Eigen::Matrix4d& p, double x, double d) {
  const Eigen::Vector4d c = p * Eigen::Vector4d(x, 0, -d, 1);
  return c.x() / c.w();
}

TEST(OffAxisProjection, ZeroParallaxAtConvergenceAndSeparationAtInfinity) {
  const double fov = 0.6, aspect = 1.5, n = 0.01, f = 10.0, conv = 0.5, s = 0.02;  // eyes at ±s
  const Eigen::Matrix4d left = viewer::off_axis_projection(fov, aspect, n, f, conv, -s);
  const Eigen::Matrix4d right = viewer::off_axis_projection(fov, aspect, n, f, conv, s);
  const Eigen::Matrix4d mono = viewer::off_axis_projection(fov, aspect, n, f, conv, 0.0);
  // The eyes sit at ±s: a world point at x = 0 is at eye x = +s for the left eye, −s for the right.
  EXPECT_NEAR(ndc_x(left, s, conv), ndc_x(right, -s, conv), 1e-12);
  EXPECT_NEAR(ndc_x(left, s, conv), 0.0, 1e-12);
  // Parallax of a point at distance d: 2s·(1/D − 1/d) in units of the half width at distance 1.
  const double half_w1 = aspect * std::tan(0.5 * fov);
  for (double d : {0.2, 0.5, 2.0, 1e6}) {
    const double parallax = ndc_x(right, -s, d) - ndc_x(left, s, d);
    EXPECT_NEAR(parallax, 2 * s * (1 / conv - 1 / d) / half_w1, 1e-9) << "d = " << d;
  }
  // Nearer than the convergence plane: crossed (the left eye sees it further right).
  EXPECT_GT(ndc_x(left, s, 0.2), ndc_x(right, -s, 0.2));
  // Mono is the ordinary symmetric frustum.
  EXPECT_NEAR(ndc_x(mono, 0.0, 0.3), 0.0, 1e-15);
  EXPECT_NEAR(ndc_x(mono, 0.3 * half_w1, 0.3), 1.0, 1e-12);
}

// --- rendering ------------------------------------------------------------------------------

class ViewerTest : public ::testing::Test {
 protected:
  haptics::SharedState shared_;
};

TEST_F(ViewerTest, SinusoidMeshIsDrawnWithoutGapsAndShaded) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(101);
  v.set_scene(test::display_scene(f, f));
  const Image img = v.capture();
  ASSERT_EQ(img.width, 800);
  ASSERT_EQ(img.height, 500);
  EXPECT_EQ(v.mesh_quads(), 100U * 100U);  // every cell of the grid is a quad: no gaps
  const test::RegionStats s = test::region_stats(img, v.main_view());
  // The window fills most of the main view, and its shading varies with the slope.
  EXPECT_GT(static_cast<double>(s.foreground), 0.5 * static_cast<double>(s.pixels));
  EXPECT_GT(s.stddev_luma, 20.0);
  EXPECT_GT(s.distinct_luma, 80);

  // The same window flat: one shade (the variation above comes from the normals, not noise).
  HeightField flat(f.geometry(), 0.0F);
  v.set_scene(test::display_scene(flat, flat));
  const test::RegionStats p = test::region_stats(v.capture(), v.main_view());
  EXPECT_GT(static_cast<double>(p.foreground), 0.5 * static_cast<double>(p.pixels));
  EXPECT_LT(p.stddev_luma, 0.4 * s.stddev_luma);
}

TEST_F(ViewerTest, NoDataCellsLeaveHolesOnlyThere) {
  Viewer v(shared_, test::test_options());
  HeightField f = test::sinusoid_field(101);
  for (int r = 40; r < 60; ++r)
    for (int c = 40; c < 60; ++c) f.at(r, c) = kNoData;
  v.set_scene(test::display_scene(f, f));
  const Image img = v.capture();
  // Cells touching a no-data sample are left out: (20 + 1)² quads fewer.
  EXPECT_EQ(v.mesh_quads(), 100U * 100U - 21U * 21U);
  // The hole's centre shows the background; a point outside it shows the mesh.
  const Eigen::Vector2d hole = v.project(Eigen::Vector3d(0.0, 0.0, 0.0));
  const Eigen::Vector2d solid = v.project(Eigen::Vector3d(0.03, 0.03, f.at(80, 80)));
  EXPECT_TRUE(test::is_background(img, static_cast<int>(hole.x()), static_cast<int>(hole.y())));
  EXPECT_FALSE(test::is_background(img, static_cast<int>(solid.x()), static_cast<int>(solid.y())));
}

bool is_proxy_blue(int r, int g, int b) { return b > r + 25 && b > g + 15; }

TEST_F(ViewerTest, ProxyBallIsDrawnWhereTheSnapshotSays) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(101);
  v.set_scene(test::display_scene(f, f));
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.02, -0.01, 0.0), Eigen::Vector3d(-0.03, 0.025, 0.0)}) {
    haptics::Snapshot s;
    s.tick = 10;
    s.proxy_m = haptics::Vec3::of(Eigen::Vector3d(p.x(), p.y(), 0.004 + 0.001));  // above the crests
    s.hip_m = s.proxy_m;
    shared_.snapshots.write(s);
    const Image img = v.capture();
    std::size_t n = 0;
    const Eigen::Vector2d c = test::centroid_where(img, v.main_view(), is_proxy_blue, n);
    ASSERT_GT(n, 20U) << "no blue ball drawn";
    const Eigen::Vector2d expected = v.project(s.proxy_m.eigen());
    EXPECT_NEAR(c.x(), expected.x(), 1.5);
    EXPECT_NEAR(c.y(), expected.y(), 1.5);
  }
}

TEST_F(ViewerTest, ForceArrowAppearsOnlyWithAForce) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(101);
  v.set_scene(test::display_scene(f, f));
  v.set_camera(0.0, 60.0);  // from the side, so an arrow along +z is seen along its length
  haptics::Snapshot s;
  s.tick = 5;
  s.proxy_m = haptics::Vec3::of(Eigen::Vector3d(0.0, 0.0, 0.0));
  s.hip_m = haptics::Vec3::of(Eigen::Vector3d(0.0, 0.0, -0.002));
  shared_.snapshots.write(s);
  const Image without = v.capture();
  s.force_n = haptics::Vec3::of(Eigen::Vector3d(0.0, 0.0, 6.0));
  s.tick = 6;
  shared_.snapshots.write(s);
  const Image with = v.capture();
  const auto is_arrow = [](int r, int g, int b) { return r > 150 && r > g + 80 && r > b + 80; };
  std::size_t n0 = 0, n1 = 0;
  test::centroid_where(without, v.main_view(), is_arrow, n0);
  const Eigen::Vector2d c = test::centroid_where(with, v.main_view(), is_arrow, n1);
  EXPECT_EQ(n0, 0U);
  EXPECT_GT(n1, 50U);
  // The arrow points up the screen from the proxy (+z seen from a tilted camera).
  EXPECT_LT(c.y(), v.project(s.proxy_m.eigen()).y());
}

TEST_F(ViewerTest, AnaglyphGivesSeparatedRedAndCyanImagesAtTheEyesProjections) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(101);
  v.set_scene(test::display_scene(f, f));
  v.set_eye_separation(0.06);
  const auto capture_with_ball = [&](const Eigen::Vector3d& p, std::uint64_t tick) {
    haptics::Snapshot s;
    s.tick = tick;
    s.proxy_m = s.hip_m = haptics::Vec3::of(p);
    shared_.snapshots.write(s);
    return v.capture();
  };
  const Eigen::Vector3d far_away(10.0, 10.0, 0.0);
  const Eigen::Vector3d near(0.01, 0.0, 0.05);  // 5 cm in front of the surface, towards the eyes
  // Which pixels of one channel the ball changed; their centroid.
  const auto ball_centroid = [&](const Image& a, const Image& b, int channel, std::size_t& n) {
    double sx = 0, sy = 0;
    n = 0;
    const viewer::PixelRect r = v.main_view();
    for (int y = r.y; y < r.y + r.height; ++y)
      for (int x = r.x; x < r.x + r.width; ++x)
        if (std::abs(a.at(x, y, channel) - b.at(x, y, channel)) > 25) sx += x, sy += y, ++n;
    return n ? Eigen::Vector2d(sx / static_cast<double>(n), sy / static_cast<double>(n)) : Eigen::Vector2d(-1, -1);
  };
  for (bool stereo : {false, true}) {
    v.set_stereo(stereo);
    const Image a = capture_with_ball(far_away, 1);
    const Image b = capture_with_ball(near, 2);
    std::size_t nr = 0, nc = 0;
    const Eigen::Vector2d red = ball_centroid(a, b, 0, nr);
    const Eigen::Vector2d cyan = ball_centroid(a, b, 1, nc);
    ASSERT_GT(nr, 30U);
    ASSERT_GT(nc, 30U);
    if (!stereo) {
      EXPECT_NEAR(red.x(), cyan.x(), 1.5);
      continue;
    }
    // Red = left eye, cyan = right eye; a point nearer than the convergence plane is crossed.
    EXPECT_GT(red.x() - cyan.x(), 10.0);
    EXPECT_NEAR(red.x(), v.project(near, -1).x(), 1.5);
    EXPECT_NEAR(cyan.x(), v.project(near, +1).x(), 1.5);
    EXPECT_NEAR(red.y(), cyan.y(), 1.0);
    // Each channel holds one eye's image only: the red ball is absent from the cyan channels.
    std::size_t both = 0;
    const viewer::PixelRect r = v.main_view();
    for (int y = r.y; y < r.y + r.height; ++y)
      for (int x = r.x; x < r.x + r.width; ++x)
        if (std::abs(a.at(x, y, 0) - b.at(x, y, 0)) > 25 && std::abs(a.at(x, y, 1) - b.at(x, y, 1)) > 25) ++both;
    EXPECT_LT(static_cast<double>(both), 0.2 * static_cast<double>(std::min(nr, nc)));
  }
}

TEST_F(ViewerTest, LevelCommandsFromEveryInputReachTheAppAndTheNewWindowIsDrawn) {
  const HeightField full = test::sinusoid_field(201);
  std::vector<RegionCommand> received;
  viewer::ViewerCallbacks cb;
  Viewer* self = nullptr;
  cb.on_region = [&](const RegionCommand& c) {
    received.push_back(c);
    // The app's answer to "finer": the 81 × 81 window at the centre of the grid, level 0 of 2.
    if (c.type == RegionCommandType::kFiner) self->set_scene(test::display_scene(test::crop(full, 60, 60, 81, 81), full, 0, 2));
  };
  Viewer v(shared_, test::test_options(), cb);
  self = &v;
  v.set_scene(test::display_scene(full, full, 1, 2));
  const Image coarse = v.capture();
  // A device button (bit 0) pressed: the servo's button event, drained by the next frame.
  haptics::ButtonEvent e;
  e.buttons = e.pressed = 1;
  ASSERT_TRUE(shared_.button_events.try_push(e));
  v.capture();  // drains the event; the answer is taken at the following frame
  ASSERT_EQ(received.size(), 1U);
  EXPECT_EQ(received[0].type, RegionCommandType::kFiner);
  const Image fine = v.capture();
  ASSERT_TRUE(v.scene());
  EXPECT_EQ(v.scene()->window.cols(), 81);
  // The main view shows another window: most pixels changed.
  EXPECT_GT(test::fraction_changed(coarse, fine, v.main_view()), 0.3);
  // The navigation view outlines the new window: yellow outline pixels span about 80/200 of
  // the overview instead of all of it.
  const auto outline_span = [&](const Image& img) {
    const viewer::PixelRect r = v.navigation_view();
    int lo = 1 << 30, hi = -1;
    for (int y = r.y; y < r.y + r.height; ++y)
      for (int x = r.x; x < r.x + r.width; ++x)
        if (img.at(x, y, 0) > 200 && img.at(x, y, 1) > 170 && img.at(x, y, 2) < 80) lo = std::min(lo, x), hi = std::max(hi, x);
    return hi - lo;
  };
  const int span_coarse = outline_span(coarse), span_fine = outline_span(fine);
  ASSERT_GT(span_coarse, 50);
  EXPECT_NEAR(static_cast<double>(span_fine) / span_coarse, 80.0 / 200.0, 0.05);
  // A click in the navigation view centres the window on the point under the cursor.
  const Eigen::Vector2d at = v.project_navigation(Eigen::Vector3d(0.02, -0.015, 0.0));
  ASSERT_TRUE(v.navigation_view().contains(at.x(), at.y()));
  v.left_click(at.x(), at.y());
  ASSERT_EQ(received.size(), 2U);
  EXPECT_EQ(received[1].type, RegionCommandType::kCentreAt);
  const double pixel_m = 0.1 / v.navigation_view().width;  // the overview spans less than the view
  EXPECT_NEAR(received[1].x_m, 0.02, pixel_m);
  EXPECT_NEAR(received[1].y_m, -0.015, pixel_m);
  received.erase(received.begin() + 1);
  // Keys, GUI and buttons share issue(): the same command arrives unchanged.
  v.issue({RegionCommandType::kPan, 0, 0.25, 0.0});
  ASSERT_EQ(received.size(), 2U);
  EXPECT_EQ(received[1].type, RegionCommandType::kPan);
  EXPECT_DOUBLE_EQ(received[1].dx, 0.25);
}

TEST_F(ViewerTest, MouseDrivesTheHipUnderTheCursor) {
  viewer::ViewerOptions o = test::test_options();
  o.mouse_drives_hip = true;
  Viewer v(shared_, o);
  const HeightField f = test::sinusoid_field(101);
  auto scene = test::display_scene(f, f);
  const haptics::WorkspaceMap map = scene->workspace;
  v.set_scene(scene);
  v.capture();
  // The cursor over the grid point (0.02, −0.01) at the HIP's plane (device z = 0).
  const double plane_z = map.to_grid(Eigen::Vector3d::Zero()).z();
  const Eigen::Vector2d px = v.project(Eigen::Vector3d(0.02, -0.01, plane_z));
  v.set_cursor_for_test(px.x(), px.y());
  v.capture();
  Eigen::Vector3d device;
  ASSERT_TRUE(v.mouse_target(device));
  const Eigen::Vector3d grid = map.to_grid(device);
  EXPECT_NEAR(grid.x(), 0.02, 2e-4);
  EXPECT_NEAR(grid.y(), -0.01, 2e-4);
  EXPECT_NEAR(device.z(), 0.0, 1e-12);
}

TEST_F(ViewerTest, ScreenshotPngIsWritten) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(65);
  v.set_scene(test::display_scene(f, f));
  const Image img = v.capture();
  const auto dir = test::temp_dir("png");
  const std::string path = (dir / "shot.png").string();
  viewer::write_png(img, path);
  std::ifstream in(path, std::ios::binary);
  char sig[8] = {};
  in.read(sig, 8);
  EXPECT_EQ(std::string(sig + 1, 3), "PNG");
  EXPECT_GT(std::filesystem::file_size(path), 1000U);
}

}  // namespace
}  // namespace hc

namespace hc {
namespace {

TEST(Arcball, DragsTurnTheSphereUnderTheCursor) {
  const viewer::PixelRect v{0, 0, 400, 200};  // sphere radius 100 px about (200, 100)
  const Eigen::Vector2d c(200, 100);
  EXPECT_TRUE(viewer::arcball_rotation(v, c, c).isApprox(Eigen::Quaterniond::Identity()));
  // Centre → right rim: the point facing the viewer turns to +x, a quarter turn about +y.
  const Eigen::Quaterniond q = viewer::arcball_rotation(v, c, c + Eigen::Vector2d(100, 0));
  EXPECT_TRUE((q * Eigen::Vector3d::UnitZ()).isApprox(Eigen::Vector3d::UnitX(), 1e-12));
  EXPECT_NEAR(Eigen::AngleAxisd(q).angle(), std::numbers::pi / 2, 1e-12);
  // Centre → up (pixel y decreases): a turn about −x that brings +z towards +y.
  const Eigen::Quaterniond u = viewer::arcball_rotation(v, c, c + Eigen::Vector2d(0, -50));
  const Eigen::Vector3d z = u * Eigen::Vector3d::UnitZ();
  EXPECT_GT(z.y(), 0.4);
  EXPECT_NEAR(z.x(), 0.0, 1e-12);
}

TEST_F(ViewerTest, OrientationToolTurnsTheRawCloudBeforeTheScan) {
  Viewer v(shared_, test::test_options());
  const HeightField f = test::sinusoid_field(41);
  auto scene = test::display_scene(f, f);
  // A raw cloud: a 10 cm square of points in the xy plane (z is the scan direction).
  for (int i = 0; i < 200; ++i)
    for (int j = 0; j < 200; ++j)
      scene->cloud_xyz_m.insert(scene->cloud_xyz_m.end(), {-0.05F + 0.0005F * static_cast<float>(i), -0.05F + 0.0005F * static_cast<float>(j), 0.0F});
  std::vector<Eigen::Quaterniond> asked;
  v.set_scene(scene);
  v.set_orienting(true);
  const auto width_of_points = [&](const Image& img) {
    int lo = 1 << 30, hi = -1;
    const viewer::PixelRect r = v.main_view();
    for (int y = r.y; y < r.y + r.height; ++y)
      for (int x = r.x; x < r.x + r.width; ++x)
        if (!test::is_background(img, x, y)) lo = std::min(lo, x), hi = std::max(hi, x);
    return hi - lo;
  };
  const int face_on = width_of_points(v.capture());
  EXPECT_GT(face_on, 100);
  // A quarter turn about y shows the square edge-on: a thin vertical line of points.
  v.set_orientation(Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi / 2, Eigen::Vector3d::UnitY())));
  const int edge_on = width_of_points(v.capture());
  EXPECT_LT(edge_on, face_on / 10);
  // A level change (new scene, same orientation) keeps the turn the user has not re-scanned yet.
  v.set_scene(test::display_scene(f, f));
  v.capture();
  EXPECT_TRUE(v.orientation().isApprox(Eigen::Quaterniond(Eigen::AngleAxisd(std::numbers::pi / 2, Eigen::Vector3d::UnitY()))));
}

}  // namespace
}  // namespace hc

namespace hc {
namespace {

TEST_F(ViewerTest, PanelAndHelpOverlayAreDrawnWhenShown) {
  viewer::ViewerOptions o = test::test_options();
  o.width_px = 1100;
  o.height_px = 700;
  const HeightField f = test::sinusoid_field(65);
  Image plain, with_panel;
  {
    Viewer v(shared_, o);
    v.set_scene(test::display_scene(f, f));
    plain = v.capture();
  }
  o.show_panel = true;
  o.show_help = true;
  Viewer v(shared_, o);
  v.set_scene(test::display_scene(f, f));
  v.capture();  // ImGui lays its windows out on the first frame
  with_panel = v.capture();
  // The panel has its own strip on the left; the main view starts right of it.
  EXPECT_GE(v.main_view().x, 300);
  const viewer::PixelRect strip{0, 0, 300, 700};
  EXPECT_GT(test::fraction_changed(plain, with_panel, strip), 0.5);
  // The help overlay sits in the middle of the window, over the mesh.
  const viewer::PixelRect middle{450, 250, 200, 200};
  EXPECT_GT(test::fraction_changed(plain, with_panel, middle), 0.2);
  EXPECT_EQ(viewer::controls_help().size() >= 10, true);
}

}  // namespace
}  // namespace hc
