/// The exploration viewer (viewer.hpp).

#include "hc/viewer/viewer.hpp"

#include "geometry.hpp"
#include "gl.hpp"

#include "hc/common/error.hpp"
#include "hc/haptics/device.hpp"

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>
#include <imgui_impl_glfw.h>
#include <imgui_impl_opengl3.h>
#include <imgui_internal.h>  // ImGuiWindow::DC.CursorMaxPos: the panel's layout check

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>
#include <thread>

namespace hc::viewer {

namespace {

constexpr double kDegToRad = std::numbers::pi / 180.0;
constexpr int kMaxMeshSide = 640;       // display mesh: at most this many vertices per side
constexpr int kMaxOverviewSide = 128;   // navigation mesh (small: it is redrawn every frame)
constexpr int kPanelWidthPx = 340;      // the ImGui panel's strip
const Eigen::Vector3f kBackground(0.08F, 0.09F, 0.11F);
const Eigen::Vector3f kStone(0.86F, 0.80F, 0.70F);
const Eigen::Vector3f kGrey(0.80F, 0.80F, 0.80F);  // DisplayMode::kGrey and every fallback to grey
const Eigen::Vector3f kProxyBlue(0.15F, 0.35F, 0.95F);
const Eigen::Vector3f kHipColour(0.95F, 0.85F, 0.20F);
const Eigen::Vector3f kForceColour(0.95F, 0.30F, 0.15F);
const Eigen::Vector3f kOutline(1.0F, 0.85F, 0.1F);

const char* const kVertexShader = R"(#version 330 core
layout(location = 0) in vec3 a_position;
layout(location = 1) in vec3 a_normal;
layout(location = 2) in vec3 a_colour;
uniform mat4 u_mvp;
uniform mat4 u_model;
uniform mat3 u_normal_matrix;
out vec3 v_normal;
out vec3 v_world;
out vec3 v_colour;
void main() {
  gl_Position = u_mvp * vec4(a_position, 1.0);
  v_colour = a_colour;
  v_normal = u_normal_matrix * a_normal;
  v_world = (u_model * vec4(a_position, 1.0)).xyz;
  gl_PointSize = 2.0;
}
)";

const char* const kFragmentShader = R"(#version 330 core
in vec3 v_normal;
in vec3 v_world;
in vec3 v_colour;
uniform vec3 u_colour;
uniform int u_vertex_colour;  // 1: the mesh's per-vertex colour instead of u_colour
uniform vec3 u_light_dir;     // towards the light, world frame, unit
uniform vec3 u_eye;           // camera position, world frame
uniform int u_lit;            // 0: flat colour
uniform int u_height_colour;  // 1: colour by world z over u_height_range
uniform vec2 u_height_range;
uniform int u_grey;           // 1: luminance only (anaglyph)
out vec4 frag_colour;
void main() {
  vec3 c = u_vertex_colour == 1 ? v_colour : u_colour;
  if (u_height_colour == 1) {
    float t = clamp((v_world.z - u_height_range.x) / max(u_height_range.y - u_height_range.x, 1e-9), 0.0, 1.0);
    c = mix(vec3(0.20, 0.28, 0.50), vec3(0.95, 0.88, 0.72), t);
  }
  if (u_lit == 1) {
    vec3 n = normalize(v_normal);
    if (!gl_FrontFacing) n = -n;
    float diffuse = max(dot(n, u_light_dir), 0.0);
    vec3 h = normalize(u_light_dir + normalize(u_eye - v_world));
    float specular = pow(max(dot(n, h), 0.0), 40.0) * 0.25;
    c = c * (0.16 + 0.84 * diffuse) + vec3(specular);
  }
  if (u_grey == 1) c = vec3(dot(c, vec3(0.299, 0.587, 0.114)));
  frag_colour = vec4(c, 1.0);
}
)";

std::string glfw_error_text;

void glfw_error(int code, const char* text) { glfw_error_text = "GLFW error " + std::to_string(code) + ": " + text; }

Eigen::Matrix4d look_at(const Eigen::Vector3d& eye, const Eigen::Vector3d& target, const Eigen::Vector3d& up) {
  const Eigen::Vector3d f = (target - eye).normalized();
  const Eigen::Vector3d s = f.cross(up).normalized();
  const Eigen::Vector3d u = s.cross(f);
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.block<1, 3>(0, 0) = s.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -s.dot(eye);
  m(1, 3) = -u.dot(eye);
  m(2, 3) = f.dot(eye);
  return m;
}

Eigen::Matrix4d ortho(double l, double r, double b, double t, double n, double f) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m(0, 0) = 2 / (r - l);
  m(1, 1) = 2 / (t - b);
  m(2, 2) = -2 / (f - n);
  m(0, 3) = -(r + l) / (r - l);
  m(1, 3) = -(t + b) / (t - b);
  m(2, 3) = -(f + n) / (f - n);
  return m;
}

/// Extent of a height field: x/y bounds of the samples and the range of finite heights.
struct Extent {
  double x_min = 0, x_max = 0, y_min = 0, y_max = 0, z_min = 0, z_max = 0;
  double size() const { return std::max(x_max - x_min, y_max - y_min); }
  Eigen::Vector3d centre() const { return {0.5 * (x_min + x_max), 0.5 * (y_min + y_max), 0.5 * (z_min + z_max)}; }
};

Extent extent_of(const HeightField& f) {
  Extent e;
  const GridGeometry& g = f.geometry();
  e.x_min = g.x0_m;
  e.x_max = g.x_of_col(std::max(0, g.cols - 1));
  e.y_min = g.y0_m;
  e.y_max = g.y_of_row(std::max(0, g.rows - 1));
  double lo = 1e300, hi = -1e300;
  for (float v : f.values()) {
    if (std::isfinite(v)) {
      lo = std::min(lo, static_cast<double>(v));
      hi = std::max(hi, static_cast<double>(v));
    }
  }
  if (lo > hi) lo = hi = 0.0;
  e.z_min = lo;
  e.z_max = hi;
  return e;
}

Eigen::Matrix4f to_f(const Eigen::Matrix4d& m) { return m.cast<float>(); }

/// The outline segments clipped to [x_min, x_max] × [y_min, y_max] of `clip` (they are axis
/// parallel, so clipping is a clamp of the varying coordinate), as GL_LINES at height z_m.
void upload_region_lines(gl::Mesh& mesh, const std::vector<RegionSegment>& segments, const Extent& clip, double z_m) {
  std::vector<float> v, colours;
  std::vector<std::uint32_t> idx;
  const auto z = static_cast<float>(z_m);
  for (const RegionSegment& sg : segments) {
    double x0 = sg.x0_m, x1 = sg.x1_m, y0 = sg.y0_m, y1 = sg.y1_m;
    if (std::max(x0, x1) < clip.x_min || std::min(x0, x1) > clip.x_max) continue;
    if (std::max(y0, y1) < clip.y_min || std::min(y0, y1) > clip.y_max) continue;
    x0 = std::clamp(x0, clip.x_min, clip.x_max), x1 = std::clamp(x1, clip.x_min, clip.x_max);
    y0 = std::clamp(y0, clip.y_min, clip.y_max), y1 = std::clamp(y1, clip.y_min, clip.y_max);
    if (x0 == x1 && y0 == y1) continue;
    const Eigen::Vector3f c = region_colour(sg.region);
    for (const auto& [x, y] : {std::pair{x0, y0}, std::pair{x1, y1}}) {
      v.insert(v.end(), {static_cast<float>(x), static_cast<float>(y), z, 0.0F, 0.0F, 1.0F});
      colours.insert(colours.end(), {c.x(), c.y(), c.z()});
      idx.push_back(static_cast<std::uint32_t>(idx.size()));
    }
  }
  mesh.upload(v, idx, GL_LINES, false, colours);
}

}  // namespace

const std::vector<std::string>& controls_help() {
  static const std::vector<std::string> lines = {
      "H / F1       this help",
      "Esc / Q      quit (Esc leaves the orientation tool first)",
      "G            show / hide the panel;   N  navigation view",
      "+ / PageUp   finer level (smaller window);   - / PageDown  coarser",
      "0 ... 9      go to level n (0 = finest)",
      "arrow keys   pan the window by a quarter of its width",
      "click        in the navigation view: centre the window there",
      "right drag   orbit the camera;   R  reset the camera",
      "wheel        mouse device: HIP height (1 mm per notch); otherwise zoom",
      "Ctrl+wheel   zoom",
      "Space        arm / disarm the device (forces on / off)",
      "S            red/cyan anaglyph on / off;   [ ]  eye separation",
      "A            audio regions: outlines on / off",
      "C            colours: scan colour -> shaded grey -> layer map -> scan colour",
      "L            layer map: texture -> mu_d -> cross-check error (turns the layer map on)",
      "O            orientation tool: left drag turns the raw cloud (arcball)",
      "Enter        re-scan the cloud with that orientation (new scene, no restart)",
      "device buttons  1 finer, 2 coarser, 3 pan left, 4 pan right",
  };
  return lines;
}

DisplayChoice display_choice_from_string(const std::string& text, const std::string& what) {
  if (text == "colour") return {DisplayMode::kColour, MapLayer::kTexture};
  if (text == "grey") return {DisplayMode::kGrey, MapLayer::kTexture};
  if (text == "texture") return {DisplayMode::kLayerMap, MapLayer::kTexture};
  if (text == "mu_d") return {DisplayMode::kLayerMap, MapLayer::kMuD};
  if (text == "error") return {DisplayMode::kLayerMap, MapLayer::kError};
  throw ConfigError(what + " '" + text + "' is unknown (expected colour, grey, texture, mu_d or error)");
}

std::string to_string(const DisplayChoice& choice) {
  switch (choice.mode) {
    case DisplayMode::kColour: return "colour";
    case DisplayMode::kGrey: return "grey";
    case DisplayMode::kLayerMap: break;
  }
  switch (choice.layer) {
    case MapLayer::kTexture: return "texture";
    case MapLayer::kMuD: return "mu_d";
    case MapLayer::kError: return "error";
  }
  return "texture";
}

std::string to_string(MapLayer layer) {
  switch (layer) {
    case MapLayer::kTexture: return "texture h [mm]";
    case MapLayer::kMuD: return "mu_d [-]";
    case MapLayer::kError: return "cross-check error [mm]";
  }
  return "";
}

Eigen::Vector3f layer_colour_map(double t) {
  // The stops of the documented map (viewer.hpp), at t = 0, 0.25, 0.5, 0.75, 1.
  static constexpr float kStops[5][3] = {
      {0.23F, 0.18F, 0.75F}, {0.15F, 0.55F, 0.90F}, {0.20F, 0.78F, 0.55F}, {0.95F, 0.80F, 0.20F}, {0.85F, 0.15F, 0.10F}};
  if (std::isnan(t)) return {0.5F, 0.5F, 0.5F};
  const double u = 4.0 * std::clamp(t, 0.0, 1.0);
  const int i = std::min(3, static_cast<int>(u));
  const auto f = static_cast<float>(u - i);
  return {kStops[i][0] + f * (kStops[i + 1][0] - kStops[i][0]), kStops[i][1] + f * (kStops[i + 1][1] - kStops[i][1]),
          kStops[i][2] + f * (kStops[i + 1][2] - kStops[i][2])};
}

double LayerRange::t(double v) const {
  if (std::isnan(v)) return v;
  return std::clamp((v - lo) / (hi - lo), 0.0, 1.0);
}

LayerRange layer_range(const HeightField& layer, MapLayer which) {
  std::vector<double> v;
  v.reserve(layer.values().size());
  for (float x : layer.values()) {
    if (std::isfinite(x)) v.push_back(which == MapLayer::kTexture ? std::abs(static_cast<double>(x)) : static_cast<double>(x));
  }
  LayerRange r{0.0, 0.0};
  if (!v.empty()) {
    const auto quantile = [&](double q) {
      const auto k = static_cast<std::ptrdiff_t>(std::lround(q * static_cast<double>(v.size() - 1)));
      std::nth_element(v.begin(), v.begin() + k, v.end());
      return v[static_cast<std::size_t>(k)];
    };
    switch (which) {
      case MapLayer::kTexture: {
        const double a = quantile(0.98);
        r = {-a, a};
        break;
      }
      case MapLayer::kMuD: {
        const double lo = quantile(0.02);
        r = {lo, quantile(0.98)};
        break;
      }
      case MapLayer::kError: r = {0.0, quantile(0.98)}; break;
    }
  }
  if (!(r.hi > r.lo)) {
    // A constant layer: the error map keeps 0 at the bottom (no error is the best colour); a
    // constant texture (e.g. 0 everywhere) or μ_d sits in the middle of the map.
    const double eps = std::max(1e-12, 1e-9 * std::abs(r.lo));
    if (which == MapLayer::kError) {
      r.hi = r.lo + eps;
    } else {
      r = {r.lo - eps, r.lo + eps};
    }
  }
  return r;
}

Eigen::Matrix4d off_axis_projection(double fov_y_rad, double aspect, double near, double far, double convergence,
                                    double eye_offset) {
  const double top = near * std::tan(0.5 * fov_y_rad);
  const double half_w = aspect * top;
  const double shift = eye_offset * near / convergence;
  const double l = -half_w - shift, r = half_w - shift, b = -top, t = top;
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m(0, 0) = 2 * near / (r - l);
  m(0, 2) = (r + l) / (r - l);
  m(1, 1) = 2 * near / (t - b);
  m(1, 2) = (t + b) / (t - b);
  m(2, 2) = -(far + near) / (far - near);
  m(2, 3) = -2 * far * near / (far - near);
  m(3, 2) = -1;
  return m;
}

/// Everything on the GPU, plus what was derived from the current scene.
struct Viewer::Gpu {
  gl::Program program;
  gl::Framebuffer target;
  gl::Mesh window_mesh, overview_mesh, sphere, arrow, outline, cloud;
  // The audio-region outlines (GL_LINES, per-vertex colour): clipped to the window at its top
  // height (main view), and whole at the overview's top height (navigation view).
  gl::Mesh regions_main, regions_navigation;
  std::size_t window_quads = 0;
  Extent window_extent, overview_extent, cloud_extent;
  bool has_cloud = false;
};

Viewer::Viewer(haptics::SharedState& shared, const ViewerOptions& options, ViewerCallbacks callbacks)
    : shared_(shared), options_(options), callbacks_(std::move(callbacks)) {
  if (options.width_px < 64 || options.height_px < 64 || options.width_px > 8192 || options.height_px > 8192) {
    throw ConfigError("viewer: window size " + std::to_string(options.width_px) + "x" + std::to_string(options.height_px) +
                      " is out of range (expected 64..8192 pixels per side)");
  }
  if (!(options.field_of_view_deg > 5.0 && options.field_of_view_deg < 120.0)) {
    throw ConfigError("viewer: field_of_view_deg " + std::to_string(options.field_of_view_deg) +
                      " is out of range (expected (5, 120))");
  }
  stereo_ = options.stereo;
  display_ = options.display;
  set_eye_separation(options.eye_separation);
  show_panel_ = options.show_panel;
  show_regions_ = options.show_regions;
  show_help_ = options.show_help;
  show_navigation_ = options.show_navigation;
  stiffness_ = static_cast<float>(options.stiffness_n_per_m);
  rho_ = static_cast<float>(options.rho);
  friction_enabled_ = options.friction_enabled;
  texture_enabled_ = options.surface.texture_enabled;
  mu_s_ = static_cast<float>(options.surface.mu_s);
  friction_model_ = options.surface.friction_model == "curvature" ? 1 : 0;
  volume_ = static_cast<float>(options.audio_volume);

  glfwSetErrorCallback(glfw_error);
  if (glfwInit() == GLFW_FALSE) {
    const char* display = std::getenv("DISPLAY");
    throw ResourceError("viewer: GLFW could not start (" + glfw_error_text + "); DISPLAY is '" +
                        (display ? display : "") + "': run on a desktop, or under `xvfb-run -a -s \"-screen 0 1280x1024x24 -noreset\"`");
  }
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  glfwWindowHint(GLFW_VISIBLE, options.visible ? GLFW_TRUE : GLFW_FALSE);
  window_ = glfwCreateWindow(options.width_px, options.height_px, options.title.c_str(), nullptr, nullptr);
  if (window_ == nullptr) {
    throw ResourceError("viewer: no OpenGL 3.3 core context (" + glfw_error_text +
                        "); check the graphics driver (Mesa's llvmpipe works under Xvfb)");
  }
  glfwMakeContextCurrent(window_);
  glfwSwapInterval(options.vsync ? 1 : 0);
  glfwSetWindowUserPointer(window_, this);
  glfwSetKeyCallback(window_, &Viewer::on_key);
  glfwSetScrollCallback(window_, &Viewer::on_scroll);
  glfwSetMouseButtonCallback(window_, &Viewer::on_mouse_button);

  try {
    gpu_ = std::make_unique<Gpu>();
    gpu_->program = gl::Program(kVertexShader, kFragmentShader);
    const MeshData sphere = sphere_mesh(24, 16);
    gpu_->sphere.upload(sphere.vertices, sphere.indices, GL_TRIANGLES);
    const MeshData arrow = arrow_mesh(16);
    gpu_->arrow.upload(arrow.vertices, arrow.indices, GL_TRIANGLES);
  } catch (...) {
    gpu_.reset();
    glfwDestroyWindow(window_);
    throw;
  }
  // ImGui chains the callbacks installed above (they are called first).
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;
  ImGui::StyleColorsDark();
  // A compact layout, so the whole panel fits an 800-pixel-high window without scrolling.
  ImGui::GetStyle().ItemSpacing.y = 3.0F;
  ImGui::GetStyle().FramePadding.y = 2.0F;
  ImGui_ImplGlfw_InitForOpenGL(window_, true);
  ImGui_ImplOpenGL3_Init("#version 330 core");
  last_frame_start_s_ = glfwGetTime();
}

Viewer::~Viewer() {
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  gpu_.reset();  // GL objects go while the context is current
  glfwDestroyWindow(window_);
  // GLFW stays initialised for the rest of the process (glfwInit() is idempotent, so the next
  // viewer reuses it): glfwTerminate() would unload the OpenGL driver, and LeakSanitizer then
  // reports the driver's bookkeeping, no longer reachable from its unmapped globals, as leaks.
}

void Viewer::set_scene(std::shared_ptr<const DisplayScene> scene) {
  const std::lock_guard<std::mutex> lock(pending_mutex_);
  pending_ = std::move(scene);
}

void Viewer::set_eye_separation(double ratio) {
  eye_separation_ = std::clamp(std::isfinite(ratio) ? ratio : 0.03, 0.001, 0.2);
}

void Viewer::set_camera(double yaw_deg, double tilt_deg, double zoom) {
  yaw_deg_ = yaw_deg;
  tilt_deg_ = std::clamp(tilt_deg, 0.0, 85.0);
  zoom_ = std::clamp(zoom, 0.1, 20.0);
}

void Viewer::request_close() { close_requested_ = true; }

std::size_t Viewer::mesh_quads() const { return gpu_->window_quads; }

void Viewer::take_pending_scene() {
  std::shared_ptr<const DisplayScene> next;
  {
    const std::lock_guard<std::mutex> lock(pending_mutex_);
    next = std::move(pending_);
    pending_.reset();
  }
  if (!next) return;
  const bool first = !scene_;
  scene_ = std::move(next);
  rebuild_scene_meshes();
  gpu_->has_cloud = scene_->cloud_xyz_m.size() >= 3;
  if (gpu_->has_cloud) {
    std::vector<float> v;
    const std::size_t n = scene_->cloud_xyz_m.size() / 3;
    v.reserve(n * 6);
    std::vector<std::uint32_t> idx(n);
    double r2 = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const float* p = &scene_->cloud_xyz_m[3 * i];
      v.insert(v.end(), {p[0], p[1], p[2], 0.0F, 0.0F, 1.0F});
      idx[i] = static_cast<std::uint32_t>(i);
      r2 = std::max(r2, static_cast<double>(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]));
    }
    gpu_->cloud.upload(v, idx, GL_POINTS);
    const double r = std::sqrt(r2);
    gpu_->cloud_extent = Extent{-r, r, -r, r, -r, r};
  }
  // A new orientation (first scene, re-scan) resets the tool; level and window changes keep
  // what the user has turned but not yet re-scanned.
  if (first || !scene_->orientation.isApprox(scene_orientation_)) orientation_ = scene_->orientation;
  scene_orientation_ = scene_->orientation;
  gui_level_ = scene_->level;
  if (first && options_.mouse_drives_hip) hip_device_z_m_ = 0.0;
}

namespace {
/// Per-sample colours (rows·cols·3 floats) of `field` under `choice`, or empty for the uniform
/// grey; `missing` says why a colour or layer was not available, `range` gets the layer map's
/// range.
std::vector<float> sample_colours(const HeightField& field, const DisplayLayers& layers, const DisplayChoice& choice,
                                  LayerRange& range, std::string& missing) {
  const std::size_t n = field.values().size();
  std::vector<float> rgb;
  missing.clear();
  if (choice.mode == DisplayMode::kColour) {
    if (layers.colour_rgb8.size() != 3 * n || n == 0) {
      missing = "this scene has no colour layer: drawn grey";
      return rgb;
    }
    rgb.resize(3 * n);
    for (std::size_t k = 0; k < 3 * n; ++k) rgb[k] = static_cast<float>(layers.colour_rgb8[k]) / 255.0F;
    return rgb;
  }
  if (choice.mode != DisplayMode::kLayerMap) return rgb;
  const HeightField& layer = choice.layer == MapLayer::kTexture ? layers.texture_m
                             : choice.layer == MapLayer::kMuD   ? layers.mu_d
                                                                : layers.cell_error_m;
  if (layer.values().size() != n || n == 0) {
    missing = choice.layer == MapLayer::kTexture ? "no texture layer in this scene: drawn grey"
              : choice.layer == MapLayer::kMuD   ? "no mu_d layer in this scene: drawn grey"
                                                 : "no cross-check error in this scene (run it with cross_check "
                                                   "enabled): drawn grey";
    return rgb;
  }
  range = layer_range(layer, choice.layer);
  rgb.resize(3 * n);
  for (std::size_t k = 0; k < n; ++k) {
    const Eigen::Vector3f c = layer_colour_map(range.t(static_cast<double>(layer.data()[k])));
    rgb[3 * k] = c.x();
    rgb[3 * k + 1] = c.y();
    rgb[3 * k + 2] = c.z();
  }
  return rgb;
}
}  // namespace

void Viewer::rebuild_scene_meshes() {
  display_dirty_ = false;
  if (!scene_) return;
  std::string missing;
  const std::vector<float> wc = sample_colours(scene_->window, scene_->window_layers, display_, window_range_, missing);
  display_note_ = missing;
  MeshData w = height_field_mesh(scene_->window, kMaxMeshSide, &wc);
  gpu_->window_mesh.upload(w.vertices, w.indices, GL_TRIANGLES, false, w.colours);
  gpu_->window_quads = w.quads;
  gpu_->window_extent = extent_of(scene_->window);
  const bool own_overview = scene_->overview.rows() > 1;
  const HeightField& ov = own_overview ? scene_->overview : scene_->window;
  const std::vector<float> oc =
      sample_colours(ov, own_overview ? scene_->overview_layers : scene_->window_layers, display_, overview_range_, missing);
  MeshData o = height_field_mesh(ov, kMaxOverviewSide, &oc);
  gpu_->overview_mesh.upload(o.vertices, o.indices, GL_TRIANGLES, false, o.colours);
  gpu_->overview_extent = extent_of(ov);
  // Audio-region outlines (computed once per raster): the window's share (its cells reach half
  // a cell past the nodes), and the whole outline for the navigation view.
  if (scene_->region_id != outline_source_) {
    outline_source_ = scene_->region_id;
    outline_ = outline_source_ ? region_outline_segments(*outline_source_) : std::vector<RegionSegment>{};
    outline_uploaded_ = false;
  }
  const std::vector<RegionSegment>& outline = outline_;
  Extent clip = gpu_->window_extent;
  const double half = 0.5 * scene_->window.geometry().cell_size_m;
  clip.x_min -= half, clip.x_max += half, clip.y_min -= half, clip.y_max += half;
  upload_region_lines(gpu_->regions_main, outline, clip, gpu_->window_extent.z_max);
  if (!outline_uploaded_ || gpu_->overview_extent.z_max != outline_z_m_) {
    Extent all;
    all.x_min = all.y_min = -1e300;
    all.x_max = all.y_max = 1e300;
    upload_region_lines(gpu_->regions_navigation, outline, all, gpu_->overview_extent.z_max);
    outline_uploaded_ = true;
    outline_z_m_ = gpu_->overview_extent.z_max;
  }
}

double Viewer::proxy_ball_radius_px(int view_height_px) { return std::max(5.0, 0.0125 * view_height_px); }

void Viewer::set_display(const DisplayChoice& choice) {
  if (choice == display_) return;
  display_ = choice;
  display_dirty_ = true;
}

void Viewer::cycle_display_mode() {
  DisplayChoice c = display_;
  c.mode = c.mode == DisplayMode::kColour ? DisplayMode::kGrey
           : c.mode == DisplayMode::kGrey ? DisplayMode::kLayerMap
                                          : DisplayMode::kColour;
  set_display(c);
}

void Viewer::cycle_map_layer() {
  DisplayChoice c = display_;
  if (c.mode == DisplayMode::kLayerMap) {
    c.layer = c.layer == MapLayer::kTexture ? MapLayer::kMuD : c.layer == MapLayer::kMuD ? MapLayer::kError : MapLayer::kTexture;
  }
  c.mode = DisplayMode::kLayerMap;
  set_display(c);
}

void Viewer::issue(const RegionCommand& command) {
  if (callbacks_.on_region) callbacks_.on_region(command);
}

void Viewer::press_device_buttons(std::uint32_t pressed) {
  if ((pressed & 1U) != 0) issue({RegionCommandType::kFiner});
  if ((pressed & 2U) != 0) issue({RegionCommandType::kCoarser});
  if ((pressed & 4U) != 0) issue({RegionCommandType::kPan, 0, -0.25, 0.0});
  if ((pressed & 8U) != 0) issue({RegionCommandType::kPan, 0, 0.25, 0.0});
}

bool Viewer::mouse_target(Eigen::Vector3d& device_m) const {
  if (!have_mouse_target_) return false;
  device_m = mouse_target_m_;
  return true;
}

void Viewer::set_cursor_for_test(double px, double py) {
  cursor_override_ = true;
  cursor_x_ = px;
  cursor_y_ = py;
}

PixelRect Viewer::main_view() const {
  int w = 0, h = 0;
  glfwGetFramebufferSize(window_, &w, &h);
  // The panel has its own strip on the left (when the window is wide enough for it).
  const int panel = show_panel_ && w >= 3 * kPanelWidthPx ? kPanelWidthPx : 0;
  if (!show_navigation_ || orienting_) return {panel, 0, w - panel, h};
  const int nav = std::min(h, w * 3 / 10);
  return {panel, 0, w - nav - panel, h};
}

PixelRect Viewer::navigation_view() const {
  int w = 0, h = 0;
  glfwGetFramebufferSize(window_, &w, &h);
  if (!show_navigation_ || orienting_) return {w, 0, 0, 0};
  const int nav = std::min(h, w * 3 / 10);
  return {w - nav, 0, nav, nav};
}

// --- cameras -------------------------------------------------------------------------------

namespace {
struct MainCamera {
  Eigen::Vector3d target, eye, up, right;
  double distance = 1.0;
};

MainCamera main_camera(const Extent& e, double fov_deg, double yaw_deg, double tilt_deg, double zoom, double aspect) {
  MainCamera c;
  c.target = e.centre();
  const double half = 0.5 * std::max(e.size(), 1e-6);
  // Fit the window's half size (times a margin) in the narrower of the two fields of view.
  const double tan_half = std::tan(0.5 * fov_deg * kDegToRad) * std::min(1.0, aspect);
  c.distance = 1.15 * half / tan_half / zoom;
  const Eigen::Matrix3d r = (Eigen::AngleAxisd(yaw_deg * kDegToRad, Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(tilt_deg * kDegToRad, Eigen::Vector3d::UnitX()))
                                .toRotationMatrix();
  c.eye = c.target + r * Eigen::Vector3d(0, 0, c.distance);
  c.up = r * Eigen::Vector3d::UnitY();
  c.right = r * Eigen::Vector3d::UnitX();
  return c;
}
}  // namespace

Eigen::Matrix4d Viewer::main_view_matrix(double eye_offset) const {
  const PixelRect v = main_view();
  const double aspect = static_cast<double>(std::max(1, v.width)) / std::max(1, v.height);
  const Extent& e = orienting_ ? gpu_->cloud_extent : gpu_->window_extent;
  const MainCamera c = main_camera(e, options_.field_of_view_deg, orienting_ ? 0.0 : yaw_deg_,
                                   orienting_ ? 0.0 : tilt_deg_, zoom_, aspect);
  return look_at(c.eye + eye_offset * c.right, c.target + eye_offset * c.right, c.up);
}

Eigen::Matrix4d Viewer::main_projection(const PixelRect& view, double eye_offset) const {
  const double aspect = static_cast<double>(std::max(1, view.width)) / std::max(1, view.height);
  const Extent& e = orienting_ ? gpu_->cloud_extent : gpu_->window_extent;
  const MainCamera c = main_camera(e, options_.field_of_view_deg, yaw_deg_, tilt_deg_, zoom_, aspect);
  return off_axis_projection(options_.field_of_view_deg * kDegToRad, aspect, 0.05 * c.distance, 20.0 * c.distance,
                             c.distance, eye_offset);
}

Eigen::Matrix4d Viewer::navigation_projection(const PixelRect& view) const {
  const Extent& e = gpu_->overview_extent;
  const double aspect = static_cast<double>(std::max(1, view.width)) / std::max(1, view.height);
  const Eigen::Vector3d c = e.centre();
  double half_w = 0.55 * std::max(e.x_max - e.x_min, 1e-6), half_h = 0.55 * std::max(e.y_max - e.y_min, 1e-6);
  if (half_w / half_h < aspect) half_w = half_h * aspect; else half_h = half_w / aspect;
  const double depth = std::max(1.0, 10.0 * std::abs(e.z_max) + 10.0 * std::abs(e.z_min) + 1.0);
  return ortho(c.x() - half_w, c.x() + half_w, c.y() - half_h, c.y() + half_h, -depth, depth);
}

double Viewer::eye_offset_for(int eye) const {
  if (eye == 0 || !gpu_) return 0.0;
  const PixelRect v = main_view();
  const double aspect = static_cast<double>(std::max(1, v.width)) / std::max(1, v.height);
  const Extent& e = orienting_ ? gpu_->cloud_extent : gpu_->window_extent;
  const MainCamera c = main_camera(e, options_.field_of_view_deg, yaw_deg_, tilt_deg_, zoom_, aspect);
  return 0.5 * eye * eye_separation_ * c.distance;
}

Eigen::Vector2d Viewer::project(const Eigen::Vector3d& grid_m, int eye) const {
  const PixelRect v = main_view();
  const double s = eye_offset_for(eye);
  const Eigen::Vector4d clip = main_projection(v, s) * main_view_matrix(s) * grid_m.homogeneous();
  const Eigen::Vector2d ndc = clip.head<2>() / clip.w();
  return {v.x + 0.5 * (ndc.x() + 1.0) * v.width, v.y + 0.5 * (1.0 - ndc.y()) * v.height};
}

// --- input ---------------------------------------------------------------------------------

void Viewer::on_key(GLFWwindow* w, int key, int, int action, int mods) {
  auto* self = static_cast<Viewer*>(glfwGetWindowUserPointer(w));
  if (self == nullptr || action == GLFW_RELEASE) return;
  if (ImGui::GetCurrentContext() != nullptr && ImGui::GetIO().WantCaptureKeyboard) return;
  const bool repeat = action == GLFW_REPEAT;
  switch (key) {
    case GLFW_KEY_ESCAPE:
      if (self->orienting_) self->orienting_ = false; else self->close_requested_ = true;
      break;
    case GLFW_KEY_Q: if (!repeat) self->close_requested_ = true; break;
    case GLFW_KEY_H:
    case GLFW_KEY_F1: if (!repeat) self->show_help_ = !self->show_help_; break;
    case GLFW_KEY_G: if (!repeat) self->show_panel_ = !self->show_panel_; break;
    case GLFW_KEY_N: if (!repeat) self->show_navigation_ = !self->show_navigation_; break;
    case GLFW_KEY_S: if (!repeat) self->stereo_ = !self->stereo_; break;
    case GLFW_KEY_A: if (!repeat) self->show_regions_ = !self->show_regions_; break;
    case GLFW_KEY_C: if (!repeat) self->cycle_display_mode(); break;
    case GLFW_KEY_L: if (!repeat) self->cycle_map_layer(); break;
    case GLFW_KEY_LEFT_BRACKET: self->set_eye_separation(self->eye_separation_ / 1.2); break;
    case GLFW_KEY_RIGHT_BRACKET: self->set_eye_separation(self->eye_separation_ * 1.2); break;
    case GLFW_KEY_R: if (!repeat) self->set_camera(0.0, 0.0, 1.0); break;
    case GLFW_KEY_O: if (!repeat) self->orienting_ = !self->orienting_; break;
    case GLFW_KEY_ENTER:
      if (!repeat && self->orienting_ && self->callbacks_.on_rescan) {
        self->callbacks_.on_rescan(self->orientation_);
        self->orienting_ = false;
      }
      break;
    case GLFW_KEY_SPACE:
      if (!repeat) {
        const bool armed = self->snapshot_.device_state == static_cast<std::uint8_t>(haptics::DeviceState::kArmed);
        self->shared_.commands.try_push(haptics::Command::of(armed ? haptics::CommandType::kDisarm : haptics::CommandType::kArm));
      }
      break;
    case GLFW_KEY_PAGE_UP:
    case GLFW_KEY_EQUAL:
    case GLFW_KEY_KP_ADD: self->issue({RegionCommandType::kFiner}); break;
    case GLFW_KEY_PAGE_DOWN:
    case GLFW_KEY_MINUS:
    case GLFW_KEY_KP_SUBTRACT: self->issue({RegionCommandType::kCoarser}); break;
    case GLFW_KEY_LEFT: self->issue({RegionCommandType::kPan, 0, -0.25, 0.0}); break;
    case GLFW_KEY_RIGHT: self->issue({RegionCommandType::kPan, 0, 0.25, 0.0}); break;
    case GLFW_KEY_UP: self->issue({RegionCommandType::kPan, 0, 0.0, 0.25}); break;
    case GLFW_KEY_DOWN: self->issue({RegionCommandType::kPan, 0, 0.0, -0.25}); break;
    default:
      if (key >= GLFW_KEY_0 && key <= GLFW_KEY_9 && !repeat && (mods & GLFW_MOD_CONTROL) == 0) {
        self->issue({RegionCommandType::kSetLevel, key - GLFW_KEY_0});
      }
      break;
  }
}

void Viewer::on_scroll(GLFWwindow* w, double, double dy) {
  auto* self = static_cast<Viewer*>(glfwGetWindowUserPointer(w));
  if (self == nullptr || ImGui::GetIO().WantCaptureMouse) return;
  const bool ctrl = glfwGetKey(w, GLFW_KEY_LEFT_CONTROL) == GLFW_PRESS || glfwGetKey(w, GLFW_KEY_RIGHT_CONTROL) == GLFW_PRESS;
  if (self->options_.mouse_drives_hip && !ctrl && !self->orienting_) {
    // 1 mm of device travel per wheel notch, within the device box.
    self->hip_device_z_m_ = std::clamp(self->hip_device_z_m_ + 0.001 * dy, -0.05, 0.05);
  } else {
    self->zoom_ = std::clamp(self->zoom_ * std::pow(1.1, dy), 0.1, 20.0);
  }
}

void Viewer::on_mouse_button(GLFWwindow* w, int button, int action, int) {
  auto* self = static_cast<Viewer*>(glfwGetWindowUserPointer(w));
  if (self == nullptr) return;
  if (action == GLFW_RELEASE) {
    if (button == GLFW_MOUSE_BUTTON_RIGHT) self->orbiting_ = false;
    if (button == GLFW_MOUSE_BUTTON_LEFT) self->arcball_active_ = false;
    return;
  }
  if (ImGui::GetIO().WantCaptureMouse) return;
  double x = 0, y = 0;
  glfwGetCursorPos(w, &x, &y);
  int ww = 1, wh = 1, fw = 1, fh = 1;
  glfwGetWindowSize(w, &ww, &wh);
  glfwGetFramebufferSize(w, &fw, &fh);
  x *= static_cast<double>(fw) / std::max(1, ww);
  y *= static_cast<double>(fh) / std::max(1, wh);
  if (button == GLFW_MOUSE_BUTTON_RIGHT) {
    self->orbiting_ = true;
    self->orbit_from_x_ = x;
    self->orbit_from_y_ = y;
    return;
  }
  if (button == GLFW_MOUSE_BUTTON_LEFT) self->left_click(x, y);
}

void Viewer::left_click(double x, double y) {
  const PixelRect nav = navigation_view();
  if (!orienting_ && nav.contains(x, y) && scene_) {
    // Click in the navigation view: centre the window there.
    const Eigen::Matrix4d inv = navigation_projection(nav).inverse();
    const double nx = 2.0 * (x - nav.x) / nav.width - 1.0, ny = 1.0 - 2.0 * (y - nav.y) / nav.height;
    const Eigen::Vector4d p = inv * Eigen::Vector4d(nx, ny, 0.0, 1.0);
    RegionCommand c{RegionCommandType::kCentreAt};
    c.x_m = p.x() / p.w();
    c.y_m = p.y() / p.w();
    issue(c);
    return;
  }
  if (orienting_) {
    arcball_active_ = true;
    arcball_start_ = orientation_;
    arcball_from_px_ = Eigen::Vector2d(x, y);
  }
}

Eigen::Vector2d Viewer::project_navigation(const Eigen::Vector3d& grid_m) const {
  const PixelRect v = navigation_view();
  const Eigen::Vector4d clip = navigation_projection(v) * grid_m.homogeneous();
  const Eigen::Vector2d ndc = clip.head<2>() / clip.w();
  return {v.x + 0.5 * (ndc.x() + 1.0) * v.width, v.y + 0.5 * (1.0 - ndc.y()) * v.height};
}

namespace {
Eigen::Vector3d arcball_point(const PixelRect& v, const Eigen::Vector2d& px) {
  const double r = 0.5 * std::max(1, std::min(v.width, v.height));
  Eigen::Vector3d p((px.x() - (v.x + 0.5 * v.width)) / r, ((v.y + 0.5 * v.height) - px.y()) / r, 0.0);
  const double d2 = p.x() * p.x() + p.y() * p.y();
  if (d2 <= 1.0) p.z() = std::sqrt(1.0 - d2);
  return p.normalized();
}
}  // namespace

Eigen::Quaterniond arcball_rotation(const PixelRect& view, const Eigen::Vector2d& from_px, const Eigen::Vector2d& to_px) {
  return Eigen::Quaterniond::FromTwoVectors(arcball_point(view, from_px), arcball_point(view, to_px));
}

void Viewer::handle_input() {
  double x = cursor_x_, y = cursor_y_;
  if (!cursor_override_) {
    glfwGetCursorPos(window_, &x, &y);
    int ww = 1, wh = 1, fw = 1, fh = 1;
    glfwGetWindowSize(window_, &ww, &wh);
    glfwGetFramebufferSize(window_, &fw, &fh);
    x *= static_cast<double>(fw) / std::max(1, ww);
    y *= static_cast<double>(fh) / std::max(1, wh);
    cursor_x_ = x;
    cursor_y_ = y;
  }
  if (orbiting_) {
    yaw_deg_ -= 0.3 * (x - orbit_from_x_);
    tilt_deg_ = std::clamp(tilt_deg_ - 0.3 * (y - orbit_from_y_), 0.0, 85.0);
    orbit_from_x_ = x;
    orbit_from_y_ = y;
  }
  if (arcball_active_ && orienting_) {
    orientation_ = (arcball_rotation(main_view(), arcball_from_px_, Eigen::Vector2d(x, y)) * arcball_start_).normalized();
  }
  // Mouse device: the cursor ray meets the plane of the HIP (device z fixed by the wheel).
  const PixelRect v = main_view();
  if (options_.mouse_drives_hip && scene_ && !orienting_ && v.contains(x, y)) {
    const haptics::WorkspaceMap& map = scene_->workspace;
    const double plane_z = map.to_grid(Eigen::Vector3d(0, 0, hip_device_z_m_)).z();
    const Eigen::Matrix4d inv = (main_projection(v, 0.0) * main_view_matrix(0.0)).inverse();
    const double nx = 2.0 * (x - v.x) / v.width - 1.0, ny = 1.0 - 2.0 * (y - v.y) / v.height;
    const Eigen::Vector4d a = inv * Eigen::Vector4d(nx, ny, -1.0, 1.0), b = inv * Eigen::Vector4d(nx, ny, 1.0, 1.0);
    const Eigen::Vector3d p0 = a.head<3>() / a.w(), p1 = b.head<3>() / b.w();
    const double dz = p1.z() - p0.z();
    if (std::abs(dz) > 1e-12) {
      const double t = (plane_z - p0.z()) / dz;
      Eigen::Vector3d device = map.to_device(p0 + t * (p1 - p0));
      device.z() = hip_device_z_m_;
      if (device.allFinite()) {
        const double lim = 0.06;
        device.x() = std::clamp(device.x(), -lim, lim);
        device.y() = std::clamp(device.y(), -lim, lim);
        mouse_target_m_ = device;
        have_mouse_target_ = true;
      }
    }
  }
}

// --- drawing -------------------------------------------------------------------------------

namespace {
void viewport(const PixelRect& v, int fb_height) {
  glViewport(v.x, fb_height - (v.y + v.height), v.width, v.height);
  glScissor(v.x, fb_height - (v.y + v.height), v.width, v.height);
}
}  // namespace

void Viewer::draw_main(const PixelRect& view) {
  const gl::Program& p = gpu_->program;
  const Extent& e = gpu_->window_extent;
  const double size = std::max(e.size(), 1e-6);
  const int eyes = stereo_ ? 2 : 1;
  const int fb_h = gpu_->target.height();
  for (int k = 0; k < eyes; ++k) {
    const int eye = stereo_ ? (k == 0 ? -1 : 1) : 0;
    const double s = eye_offset_for(eye);
    if (stereo_) {
      const auto left = static_cast<GLboolean>(eye < 0 ? GL_TRUE : GL_FALSE);
      const auto right = static_cast<GLboolean>(eye < 0 ? GL_FALSE : GL_TRUE);
      glColorMask(left, right, right, GL_TRUE);
      glClear(GL_DEPTH_BUFFER_BIT);
    }
    viewport(view, fb_h);
    const Eigen::Matrix4d vp = main_projection(view, s) * main_view_matrix(s);
    const Eigen::Vector3d eye_pos = main_view_matrix(s).inverse().block<3, 1>(0, 3);
    p.use();
    p.set("u_eye", Eigen::Vector3f(eye_pos.cast<float>()));
    // A light from the viewer's upper left, fixed to the camera.
    const Eigen::Matrix3d to_world = main_view_matrix(s).block<3, 3>(0, 0).transpose();
    p.set("u_light_dir", Eigen::Vector3f((to_world * Eigen::Vector3d(-0.45, 0.55, 0.70).normalized()).cast<float>()));
    p.set("u_grey", stereo_ ? 1 : 0);
    p.set("u_height_colour", 0);
    p.set("u_vertex_colour", 0);
    const auto draw = [&](const gl::Mesh& mesh, const Eigen::Matrix4d& model, const Eigen::Vector3f& colour, bool lit) {
      p.set("u_mvp", to_f(vp * model));
      p.set("u_model", to_f(model));
      const Eigen::Matrix3d nm = model.block<3, 3>(0, 0).inverse().transpose();
      p.set("u_normal_matrix", Eigen::Matrix3f(nm.cast<float>()));
      p.set("u_colour", colour);
      p.set("u_lit", lit ? 1 : 0);
      mesh.draw();
    };
    if (orienting_) {
      if (gpu_->has_cloud) {
        Eigen::Matrix4d model = Eigen::Matrix4d::Identity();
        model.block<3, 3>(0, 0) = orientation_.toRotationMatrix();
        p.set("u_height_colour", 1);
        const double r = gpu_->cloud_extent.x_max;
        p.set("u_height_range", Eigen::Vector2f(static_cast<float>(-r), static_cast<float>(r)));
        draw(gpu_->cloud, model, kStone, false);
        p.set("u_height_colour", 0);
      }
      continue;
    }
    p.set("u_vertex_colour", gpu_->window_mesh.has_colours() ? 1 : 0);
    draw(gpu_->window_mesh, Eigen::Matrix4d::Identity(), kGrey, true);
    p.set("u_vertex_colour", 0);
    // Proxy, HIP and force (snapshot, grid frame).
    const Eigen::Vector3d proxy = snapshot_.proxy_m.eigen(), hip = snapshot_.hip_m.eigen();
    const Eigen::Vector3d force = snapshot_.force_n.eigen();
    if (show_regions_ && !gpu_->regions_main.empty()) {
      // Over the mesh whatever its height: the outlines lie at the window's top height.
      glDisable(GL_DEPTH_TEST);
      p.set("u_vertex_colour", 1);
      draw(gpu_->regions_main, Eigen::Matrix4d::Identity(), kGrey, false);
      p.set("u_vertex_colour", 0);
      glEnable(GL_DEPTH_TEST);
    }
    if (snapshot_.tick > 0 && proxy.allFinite() && hip.allFinite()) {
      // A constant size on screen: the world radius that projects to proxy_ball_radius_px at
      // the proxy's distance from the eye (perspective: pixels = r·(h/2) / (d·tan(fov/2))).
      const double depth_m = std::max(-(main_view_matrix(s) * proxy.homogeneous()).z(), 1e-9);
      const double px_per_m = 0.5 * view.height / (depth_m * std::tan(0.5 * options_.field_of_view_deg * kDegToRad));
      const double ball = proxy_ball_radius_px(view.height) / px_per_m;
      Eigen::Affine3d m = Eigen::Translation3d(proxy) * Eigen::Scaling(ball);
      draw(gpu_->sphere, m.matrix(), kProxyBlue, true);
      m = Eigen::Translation3d(hip) * Eigen::Scaling(0.45 * ball);
      draw(gpu_->sphere, m.matrix(), kHipColour, true);
      const double f = force.norm();
      if (f > 1e-3 && std::isfinite(f)) {
        const double length = 0.25 * size * std::min(1.0, f / std::max(options_.max_force_n, 1e-6));
        const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), force / f);
        const Eigen::Affine3d a = Eigen::Translation3d(proxy) * q * Eigen::Scaling(length, length, length);
        draw(gpu_->arrow, a.matrix(), kForceColour, true);
      }
    }
  }
  glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
}

void Viewer::draw_navigation(const PixelRect& view) {
  if (view.width <= 0) return;
  const int fb_h = gpu_->target.height();
  viewport(view, fb_h);
  glClearColor(0.05F, 0.05F, 0.07F, 1.0F);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  const gl::Program& p = gpu_->program;
  p.use();
  const Eigen::Matrix4d proj = navigation_projection(view);
  p.set("u_mvp", to_f(proj));
  p.set("u_model", Eigen::Matrix4f(Eigen::Matrix4f::Identity()));
  p.set("u_normal_matrix", Eigen::Matrix3f(Eigen::Matrix3f::Identity()));
  p.set("u_eye", Eigen::Vector3f(0, 0, 10));
  p.set("u_light_dir", Eigen::Vector3f(Eigen::Vector3f(-0.45F, 0.55F, 0.70F).normalized()));
  p.set("u_grey", 0);
  p.set("u_lit", 1);
  p.set("u_height_colour", 0);
  const Extent& oe = gpu_->overview_extent;
  // The display mode's colours (scan colour, layer map) or grey, lit like the main view.
  p.set("u_vertex_colour", gpu_->overview_mesh.has_colours() ? 1 : 0);
  p.set("u_colour", kGrey);
  gpu_->overview_mesh.draw();
  p.set("u_vertex_colour", 0);
  // The window outline, drawn on top.
  glDisable(GL_DEPTH_TEST);
  const Extent& we = gpu_->window_extent;
  const auto z = static_cast<float>(oe.z_max);
  const std::vector<float> v = {
      static_cast<float>(we.x_min), static_cast<float>(we.y_min), z, 0, 0, 1,
      static_cast<float>(we.x_max), static_cast<float>(we.y_min), z, 0, 0, 1,
      static_cast<float>(we.x_max), static_cast<float>(we.y_max), z, 0, 0, 1,
      static_cast<float>(we.x_min), static_cast<float>(we.y_max), z, 0, 0, 1};
  gpu_->outline.upload(v, {0, 1, 1, 2, 2, 3, 3, 0}, GL_LINES, true);
  p.set("u_lit", 0);
  if (show_regions_ && !gpu_->regions_navigation.empty()) {
    p.set("u_vertex_colour", 1);
    gpu_->regions_navigation.draw();
    p.set("u_vertex_colour", 0);
  }
  p.set("u_colour", kOutline);
  gpu_->outline.draw();
  if (snapshot_.tick > 0 && snapshot_.proxy_m.eigen().allFinite()) {
    const double r = 0.015 * std::max(oe.size(), 1e-6);
    const Eigen::Affine3d m = Eigen::Translation3d(snapshot_.proxy_m.eigen()) * Eigen::Scaling(r);
    p.set("u_mvp", to_f(proj * m.matrix()));
    p.set("u_colour", kProxyBlue);
    gpu_->sphere.draw();
  }
  glEnable(GL_DEPTH_TEST);
}

void Viewer::update_plots() {
  // Servo timing from the snapshots themselves: the mean tick period since the previous frame
  // (servo clock, so the UI's own delays do not enter), and the loop's worst tick compute time.
  float period_us = 0.0F;
  if (snapshot_.tick > last_ticks_ && last_ticks_ > 0) {
    period_us = static_cast<float>(1e6 * (snapshot_.t_s - last_plot_time_s_) / static_cast<double>(snapshot_.tick - last_ticks_));
  }
  if (snapshot_.tick != last_ticks_) {
    last_ticks_ = snapshot_.tick;
    last_plot_time_s_ = snapshot_.t_s;
  }
  force_plot_[plot_head_] = static_cast<float>(snapshot_.force_n.eigen().norm());
  rate_plot_[plot_head_] = period_us;
  plot_head_ = (plot_head_ + 1) % kPlotLength;
}

void Viewer::send_servo_settings() {
  using haptics::Command;
  using haptics::CommandType;
  shared_.commands.try_push(Command::of(CommandType::kSetStiffness, static_cast<double>(stiffness_)));
  shared_.commands.try_push(Command::of(CommandType::kSetRho, static_cast<double>(rho_)));
  shared_.commands.try_push(Command::of(CommandType::kSetFrictionEnabled, friction_enabled_ ? 1.0 : 0.0));
}

void Viewer::draw_gui() {
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
  panel_overflow_px_ = 0.0;
  if (show_panel_) {
    ImGui::SetNextWindowPos(ImVec2(4, 4), ImGuiCond_FirstUseEver);
    ImGui::SetNextWindowSize(ImVec2(kPanelWidthPx - 8, 0), ImGuiCond_FirstUseEver);
    ImGui::Begin("hapticloud");
    // Widgets leave room on their right for the longest label of the panel, so no label is
    // clipped whatever the font (panel_overflow_px() measures it).
    {
      static constexpr const char* kLabels[] = {"angles xyz [deg]", "level (0 finest)", "stiffness [N/m]", "rho",
                                                "mu_s", "friction model", "layer (L)", "eye separation",
                                                "audio volume", "|F| [N]", "tick period [us]"};
      float label_px = 0.0F;
      for (const char* l : kLabels) label_px = std::max(label_px, ImGui::CalcTextSize(l).x);
      ImGui::PushItemWidth(-(label_px + ImGui::GetStyle().ItemInnerSpacing.x + 1.0F));
    }
    if (scene_) ImGui::TextWrapped("%s", scene_->description.c_str());
    if (callbacks_.status) {
      const std::string s = callbacks_.status();
      if (!s.empty()) ImGui::TextWrapped("%s", s.c_str());
    }
    const auto device_state = static_cast<haptics::DeviceState>(snapshot_.device_state);
    ImGui::Text("device %s, %s, |F| %.2f N", haptics::to_string(device_state), snapshot_.in_contact ? "contact" : "free",
                snapshot_.force_n.eigen().norm());
    if (ImGui::Button(device_state == haptics::DeviceState::kArmed ? "Disarm (Space)" : "Arm (Space)")) {
      shared_.commands.try_push(haptics::Command::of(
          device_state == haptics::DeviceState::kArmed ? haptics::CommandType::kDisarm : haptics::CommandType::kArm));
    }
    if (device_state == haptics::DeviceState::kFault) {
      ImGui::SameLine();
      if (ImGui::Button("Reset fault")) shared_.commands.try_push(haptics::Command::of(haptics::CommandType::kResetFault));
    }
    if (ImGui::CollapsingHeader("Orientation (before the depth scan)", ImGuiTreeNodeFlags_DefaultOpen)) {
      ImGui::BeginDisabled(!callbacks_.on_rescan);
      ImGui::Checkbox("Arcball on the raw cloud (O)", &orienting_);
      ImGui::InputFloat3("angles xyz [deg]", typed_angles_deg_, "%.1f");
      if (ImGui::Button("Use angles")) {
        orientation_ = Eigen::AngleAxisd(typed_angles_deg_[0] * kDegToRad, Eigen::Vector3d::UnitX()) *
                       Eigen::AngleAxisd(typed_angles_deg_[1] * kDegToRad, Eigen::Vector3d::UnitY()) *
                       Eigen::AngleAxisd(typed_angles_deg_[2] * kDegToRad, Eigen::Vector3d::UnitZ());
      }
      ImGui::SameLine();
      if (ImGui::Button("Re-scan (Enter)")) {
        callbacks_.on_rescan(orientation_);
        orienting_ = false;
      }
      ImGui::EndDisabled();
      const Eigen::Vector3d a = orientation_.toRotationMatrix().eulerAngles(0, 1, 2) / kDegToRad;
      ImGui::Text("current: x %.1f, y %.1f, z %.1f deg", a.x(), a.y(), a.z());
    }
    if (ImGui::CollapsingHeader("Level and window", ImGuiTreeNodeFlags_DefaultOpen)) {
      const int levels = scene_ ? scene_->level_count : 1;
      ImGui::BeginDisabled(!callbacks_.on_region);
      if (ImGui::SliderInt("level (0 finest)", &gui_level_, 0, std::max(0, levels - 1))) {
        issue({RegionCommandType::kSetLevel, gui_level_});
      }
      if (ImGui::Button("finer (+)")) issue({RegionCommandType::kFiner});
      ImGui::SameLine();
      if (ImGui::Button("coarser (-)")) issue({RegionCommandType::kCoarser});
      if (ImGui::ArrowButton("left", ImGuiDir_Left)) issue({RegionCommandType::kPan, 0, -0.25, 0.0});
      ImGui::SameLine();
      if (ImGui::ArrowButton("up", ImGuiDir_Up)) issue({RegionCommandType::kPan, 0, 0.0, 0.25});
      ImGui::SameLine();
      if (ImGui::ArrowButton("down", ImGuiDir_Down)) issue({RegionCommandType::kPan, 0, 0.0, -0.25});
      ImGui::SameLine();
      if (ImGui::ArrowButton("right", ImGuiDir_Right)) issue({RegionCommandType::kPan, 0, 0.25, 0.0});
      ImGui::EndDisabled();
      if (scene_) {
        const Extent& e = gpu_->window_extent;
        ImGui::Text("window %.1f x %.1f mm at (%.1f, %.1f) mm", 1e3 * (e.x_max - e.x_min), 1e3 * (e.y_max - e.y_min),
                    1e3 * e.centre().x(), 1e3 * e.centre().y());
      }
    }
    if (ImGui::CollapsingHeader("Haptics", ImGuiTreeNodeFlags_DefaultOpen)) {
      bool servo = false;
      servo |= ImGui::SliderFloat("stiffness [N/m]", &stiffness_, 0.0F, static_cast<float>(options_.max_stiffness_n_per_m));
      servo |= ImGui::SliderFloat("rho", &rho_, 0.01F, 1.0F);
      servo |= ImGui::Checkbox("friction", &friction_enabled_);
      if (servo) send_servo_settings();
      ImGui::BeginDisabled(!callbacks_.on_surface_settings);
      bool surface = false;
      surface |= ImGui::SliderFloat("mu_s", &mu_s_, 0.0F, 1.5F);
      const char* models[] = {"paper", "curvature"};
      surface |= ImGui::Combo("friction model", &friction_model_, models, 2);
      surface |= ImGui::Checkbox("texture", &texture_enabled_);
      if (surface && callbacks_.on_surface_settings) {
        SurfaceSettings s;
        s.texture_enabled = texture_enabled_;
        s.mu_s = static_cast<double>(mu_s_);
        s.friction_model = models[friction_model_];
        callbacks_.on_surface_settings(s);
      }
      ImGui::EndDisabled();
    }
    if (ImGui::CollapsingHeader("Display", ImGuiTreeNodeFlags_DefaultOpen)) {
      DisplayChoice c = display_;
      int mode = static_cast<int>(c.mode);
      bool changed = ImGui::RadioButton("colour", &mode, 0);
      ImGui::SameLine();
      changed |= ImGui::RadioButton("grey", &mode, 1);
      ImGui::SameLine();
      changed |= ImGui::RadioButton("layer map", &mode, 2);
      ImGui::SameLine();
      ImGui::TextDisabled("C, L");
      int layer = static_cast<int>(c.layer);
      const char* layers[] = {"texture", "mu_d", "cross-check error"};
      if (ImGui::Combo("layer (L)", &layer, layers, 3)) {
        changed = true;
        mode = static_cast<int>(DisplayMode::kLayerMap);
      }
      if (changed) set_display({static_cast<DisplayMode>(mode), static_cast<MapLayer>(layer)});
      if (!display_note_.empty()) {
        ImGui::TextColored(ImVec4(1.0F, 0.75F, 0.3F, 1.0F), "%s", display_note_.c_str());
      } else if (display_.mode == DisplayMode::kLayerMap) {
        // The colour map as a bar, then the ranges it spans (low end left, high end right).
        const ImVec2 at = ImGui::GetCursorScreenPos();
        const float width = ImGui::GetContentRegionAvail().x, height = 12.0F;
        ImDrawList* dl = ImGui::GetWindowDrawList();
        const auto u32 = [](double t) {
          const Eigen::Vector3f m = layer_colour_map(t);
          return ImGui::ColorConvertFloat4ToU32(ImVec4(m.x(), m.y(), m.z(), 1.0F));
        };
        for (int i = 0; i < 4; ++i) {
          const float x0 = at.x + width * static_cast<float>(i) / 4.0F, x1 = at.x + width * static_cast<float>(i + 1) / 4.0F;
          dl->AddRectFilledMultiColor(ImVec2(x0, at.y), ImVec2(x1, at.y + height), u32(i / 4.0), u32((i + 1) / 4.0),
                                      u32((i + 1) / 4.0), u32(i / 4.0));
        }
        ImGui::Dummy(ImVec2(width, height));
        const double k = display_.layer == MapLayer::kMuD ? 1.0 : 1e3;  // m → mm
        ImGui::Text("%s", to_string(display_.layer).c_str());
        ImGui::Text("window %.4g .. %.4g", k * window_range_.lo, k * window_range_.hi);
        ImGui::Text("navigation %.4g .. %.4g", k * overview_range_.lo, k * overview_range_.hi);
        if (display_.layer == MapLayer::kError && scene_ && scene_->level > 0) {
          ImGui::TextWrapped("(level 0's error smoothed to this level)");
        }
      }
    }
    if (ImGui::CollapsingHeader("View and sound", ImGuiTreeNodeFlags_DefaultOpen)) {
      ImGui::Checkbox("anaglyph stereo (S)", &stereo_);
      ImGui::BeginDisabled(!scene_ || !scene_->region_id || scene_->region_id->rows() == 0);
      ImGui::Checkbox("audio regions (A)", &show_regions_);
      ImGui::EndDisabled();
      if (show_regions_ && scene_ && !scene_->region_names.empty()) {
        for (std::size_t i = 0; i < scene_->region_names.size(); ++i) {
          const Eigen::Vector3f c = region_colour(static_cast<std::int32_t>(i));
          // Side by side while the next name fits on the line.
          const float right = ImGui::GetWindowPos().x + ImGui::GetWindowContentRegionMax().x;
          const float need = ImGui::GetStyle().ItemSpacing.x + ImGui::CalcTextSize(scene_->region_names[i].c_str()).x;
          if (i > 0 && ImGui::GetItemRectMax().x + need <= right) ImGui::SameLine();
          ImGui::TextColored(ImVec4(c.x(), c.y(), c.z(), 1.0F), "%s", scene_->region_names[i].c_str());
        }
      }
      auto sep = static_cast<float>(eye_separation_);
      if (ImGui::SliderFloat("eye separation", &sep, 0.001F, 0.2F, "%.3f")) set_eye_separation(static_cast<double>(sep));
      ImGui::BeginDisabled(!callbacks_.on_audio_volume);
      if (ImGui::SliderFloat("audio volume", &volume_, 0.0F, 1.0F) && callbacks_.on_audio_volume) {
        callbacks_.on_audio_volume(static_cast<double>(volume_));
      }
      ImGui::EndDisabled();
    }
    if (ImGui::CollapsingHeader("Plots", ImGuiTreeNodeFlags_DefaultOpen)) {
      // Each plot with its axis values: the top and bottom of the value axis at the frame's
      // left, the time span at its bottom right, the newest value at the top.
      const double frame_s = frame_stats_.mean_frame_s > 0.0 ? frame_stats_.mean_frame_s : 1.0 / 60.0;
      const auto plot = [&](const char* label, const float* values, float lo, float hi, const char* unit) {
        const float newest = values[(plot_head_ + kPlotLength - 1) % kPlotLength];
        char now[48];
        std::snprintf(now, sizeof now, "%.4g %s", static_cast<double>(newest), unit);
        const float frame_w = ImGui::CalcItemWidth();
        ImGui::PlotLines(label, values, kPlotLength, plot_head_, now, lo, hi, ImVec2(0, 40));
        const ImVec2 a = ImGui::GetItemRectMin();
        const ImVec2 b(a.x + frame_w, ImGui::GetItemRectMax().y);
        ImDrawList* dl = ImGui::GetWindowDrawList();
        const ImU32 col = ImGui::GetColorU32(ImGuiCol_TextDisabled);
        const float pad = ImGui::GetStyle().FramePadding.y, text_h = ImGui::GetTextLineHeight();
        char t[32];
        std::snprintf(t, sizeof t, "%.4g", static_cast<double>(hi));
        dl->AddText(ImVec2(a.x + 3.0F, a.y + pad), col, t);
        std::snprintf(t, sizeof t, "%.4g", static_cast<double>(lo));
        dl->AddText(ImVec2(a.x + 3.0F, b.y - pad - text_h), col, t);
        std::snprintf(t, sizeof t, "-%.1f s", frame_s * kPlotLength);
        dl->AddText(ImVec2(b.x - 3.0F - ImGui::CalcTextSize(t).x, b.y - pad - text_h), col, t);
      };
      plot("|F| [N]", force_plot_, 0.0F, static_cast<float>(options_.max_force_n), "N");
      plot("tick period [us]", rate_plot_, 0.0F, 2000.0F, "us");
      const auto& c = shared_.counters;
      ImGui::Text("ticks %llu, overruns %llu", static_cast<unsigned long long>(c.ticks.load(std::memory_order_relaxed)),
                  static_cast<unsigned long long>(c.overruns.load(std::memory_order_relaxed)));
      ImGui::Text("worst tick %.1f us, worst lateness %.1f us",
                  1e-3 * static_cast<double>(c.worst_compute_ns.load(std::memory_order_relaxed)),
                  1e-3 * static_cast<double>(c.worst_lateness_ns.load(std::memory_order_relaxed)));
      ImGui::Text("frame %.1f ms (mean %.1f ms)", 1e3 * frame_stats_.last_frame_s, 1e3 * frame_stats_.mean_frame_s);
    }
    // How far the widest row reached past the inner right edge (0 when everything fits).
    const ImGuiWindow* win = ImGui::GetCurrentWindow();
    panel_overflow_px_ = std::max(0.0, static_cast<double>(win->DC.CursorMaxPos.x - (win->Pos.x + win->Size.x - win->ScrollbarSizes.x -
                                                                                 ImGui::GetStyle().WindowPadding.x)));
    ImGui::PopItemWidth();
    ImGui::End();
  }
  if (show_help_) {
    const ImGuiViewport* vp = ImGui::GetMainViewport();
    ImGui::SetNextWindowPos(ImVec2(vp->Size.x * 0.5F, vp->Size.y * 0.5F), ImGuiCond_Always, ImVec2(0.5F, 0.5F));
    ImGui::SetNextWindowBgAlpha(0.85F);
    ImGui::Begin("Controls", &show_help_, ImGuiWindowFlags_AlwaysAutoResize | ImGuiWindowFlags_NoCollapse);
    for (const std::string& line : controls_help()) ImGui::TextUnformatted(line.c_str());
    ImGui::End();
  }
  ImGui::Render();
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

void Viewer::render_frame() {
  const double start = glfwGetTime();
  glfwPollEvents();
  if (glfwWindowShouldClose(window_) != 0) close_requested_ = true;
  handle_input();
  if (callbacks_.on_frame) callbacks_.on_frame();
  take_pending_scene();
  if (display_dirty_) rebuild_scene_meshes();
  haptics::ButtonEvent b;
  while (shared_.button_events.try_pop(b)) press_device_buttons(b.pressed);
  haptics::Snapshot s;
  shared_.snapshots.read(s);
  if (s.tick > 0) snapshot_ = s;
  update_plots();

  int fw = 1, fh = 1;
  glfwGetFramebufferSize(window_, &fw, &fh);
  gpu_->target.ensure(std::max(1, fw), std::max(1, fh));
  glBindFramebuffer(GL_FRAMEBUFFER, gpu_->target.id());
  glDisable(GL_SCISSOR_TEST);
  glViewport(0, 0, fw, fh);
  glClearColor(kBackground.x(), kBackground.y(), kBackground.z(), 1.0F);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glEnable(GL_PROGRAM_POINT_SIZE);
  if (scene_) {
    glEnable(GL_SCISSOR_TEST);
    draw_main(main_view());
    if (!orienting_) draw_navigation(navigation_view());
    glDisable(GL_SCISSOR_TEST);
  }
  glViewport(0, 0, fw, fh);
  draw_gui();
  last_frame_start_s_ = start;
}

bool Viewer::frame() {
  render_frame();
  present();
  return !close_requested_;
}

Image Viewer::capture() {
  render_frame();
  Image img;
  img.width = gpu_->target.width();
  img.height = gpu_->target.height();
  img.rgb.resize(static_cast<std::size_t>(img.width) * static_cast<std::size_t>(img.height) * 3);
  glBindFramebuffer(GL_READ_FRAMEBUFFER, gpu_->target.id());
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  std::vector<std::uint8_t> flipped(img.rgb.size());
  glReadPixels(0, 0, img.width, img.height, GL_RGB, GL_UNSIGNED_BYTE, flipped.data());
  const std::size_t row = static_cast<std::size_t>(img.width) * 3;
  for (int y = 0; y < img.height; ++y) {
    std::copy_n(flipped.data() + static_cast<std::size_t>(img.height - 1 - y) * row, row,
                img.rgb.data() + static_cast<std::size_t>(y) * row);
  }
  present();
  return img;
}

void Viewer::present() {
  const int w = gpu_->target.width(), h = gpu_->target.height();
  glBindFramebuffer(GL_READ_FRAMEBUFFER, gpu_->target.id());
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
  glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  glfwSwapBuffers(window_);
  const double t = glfwGetTime() - last_frame_start_s_;
  ++frame_stats_.frames;
  frame_stats_.last_frame_s = t;
  frame_stats_.max_frame_s = std::max(frame_stats_.max_frame_s, t);
  frame_stats_.mean_frame_s += (t - frame_stats_.mean_frame_s) / static_cast<double>(frame_stats_.frames);
  // Without vsync (or where the server ignores it), cap the rate so the UI thread leaves the
  // CPU to the servo loop.
  if (options_.max_fps > 0.0) {
    const double next = last_frame_start_s_ + 1.0 / options_.max_fps;
    const double wait = next - glfwGetTime();
    if (wait > 0.0) std::this_thread::sleep_for(std::chrono::duration<double>(wait));
  }
}

}  // namespace hc::viewer
