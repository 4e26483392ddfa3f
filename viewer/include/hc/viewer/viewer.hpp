#pragma once
/// @file viewer.hpp
/// The exploration viewer (issue 6): a GLFW window with an OpenGL 3.3 core context that draws
/// the active haptic window as a lit quad mesh, the proxy (blue ball), the HIP (small marker)
/// and the contact force (arrow); a navigation view of the whole object with the window
/// outlined; an optional red/cyan anaglyph; a Dear ImGui panel and a help overlay.
///
/// Threads: every member function is for the ONE UI thread that constructed the viewer, except
/// set_scene() (any thread). The viewer only reads the servo loop's snapshots (triple buffer,
/// it is that buffer's one reader) and atomic counters, and pushes Commands (stiffness, ρ,
/// friction on/off) into SharedState::commands; it is that ring's one producer, so the app's
/// own commands (arm, disarm, workspace) must be sent from the same UI thread, e.g. from the
/// on_frame callback. It never waits on the servo thread and owns no scene data the servo uses.
/// The viewer does not link the pipeline: re-scans, level and region changes are requests to
/// the app through ViewerCallbacks, answered later with set_scene().

#include "hc/common/height_field.hpp"
#include "hc/haptics/shared_state.hpp"
#include "hc/haptics/workspace_map.hpp"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

struct GLFWwindow;  // GLFW's window handle (GLFW headers stay in the .cpp files)

namespace hc::viewer {

/// Per-sample layers drawn on one height field of a DisplayScene (the window or the overview).
/// Each is empty (absent) or has exactly that field's rows × cols samples, row-major, sample
/// (r, c) at the field's sample (r, c). Source: the level-of-detail pyramid's level or window
/// (hc::pipeline::LodLevel / LodWindowLayers), which the app copies in.
struct DisplayLayers {
  /// The scan's colour, rows·cols·3 bytes, R G B (8-bit, as stored in the scene's colour.png),
  /// or empty. Samples without depth may hold anything (they are not drawn).
  std::vector<std::uint8_t> colour_rgb8;
  HeightField texture_m;     ///< h = f − f_b [m] (signed), NaN = none
  HeightField mu_d;          ///< dynamic friction coefficient μ_d [-], NaN = none
  /// Cross-check error [m] ≥ 0: 3-D distance from a grid sample to its nearest input point
  /// (scene layer cell_error; at a coarser level, level 0's map smoothed down), NaN = none.
  HeightField cell_error_m;
};

/// What the viewer shows of the scene. Immutable once handed to set_scene().
struct DisplayScene {
  HeightField window;    ///< the active haptic window: rendered heights, grid frame [m], NaN = none
  HeightField overview;  ///< the whole object at a coarse level, grid frame [m] (may be empty:
                         ///< then the window itself is the overview)
  DisplayLayers window_layers;    ///< colour and layer maps of `window` (any may be empty)
  DisplayLayers overview_layers;  ///< of `overview` (ignored when the overview is empty)
  haptics::WorkspaceMap workspace;  ///< device ↔ grid map of this window
  int level = 0;                    ///< LoD level of the window (0 = finest)
  int level_count = 1;              ///< levels available
  std::string description;          ///< one line for the panel ("Buddha, level 1 of 3, ...")
  /// Optional raw-cloud preview for choosing the orientation before the depth scan: x, y, z
  /// triplets [m] in the recentred model frame (before the view rotation); empty = the
  /// orientation tool only offers typed angles.
  std::vector<float> cloud_xyz_m;
  /// The rotation that made this scene's grid from the model frame (shown and edited by the
  /// orientation tool).
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();
  /// Audio regions for the overlay (key A, panel "View and sound"): the region index per
  /// sample as a float (≥ 0; NaN = no region), on any grid of the scene's frame (the app passes
  /// the grid its region map was rasterised on: level 0's), and the regions' names by index.
  /// Null or empty: no overlay. Shared, not copied, between the scenes of one session: the
  /// viewer outlines a raster once and reuses the outline while the pointer stays the same.
  std::shared_ptr<const HeightField> region_id;
  std::vector<std::string> region_names;
};

/// One straight piece of an audio region's outline, grid frame (x, y) [m].
struct RegionSegment {
  double x0_m = 0.0, y0_m = 0.0, x1_m = 0.0, y1_m = 0.0;
  std::int32_t region = 0;  ///< index of the region whose boundary this is (the inside side's)
};

/// The outlines of the regions of `region_id` (index per sample as a float, NaN or < 0 = none):
/// the sample cell boundaries (half a cell from each node) between a sample of region i and a
/// sample not of region i (another region, none, or outside the raster), joined along rows and
/// columns into maximal straight runs. A boundary between two regions gives one segment per
/// side (each region is closed on its own). Shapes: a box of w × h samples gives 4 segments of
/// total length 2·(w + h)·cell. Real-time: no. Cost: O(rows·cols).
std::vector<RegionSegment> region_outline_segments(const HeightField& region_id);

/// The overlay colour of region `index` (linear RGB [0, 1]): well-separated hues (golden-angle
/// steps), bright enough to read on the stone grey and on every layer map.
Eigen::Vector3f region_colour(std::int32_t index);

/// Level-of-detail and region commands. Keys, mouse clicks in the navigation view, the GUI and
/// device buttons all go through Viewer::issue() and reach the app as one of these.
enum class RegionCommandType : std::uint8_t {
  kFiner = 0,   ///< one level finer (smaller window, more detail)
  kCoarser,     ///< one level coarser
  kSetLevel,    ///< level = `level`
  kPan,         ///< move the window by (dx, dy) window widths [-]
  kCentreAt,    ///< centre the window on (x_m, y_m), grid frame [m]
};

struct RegionCommand {
  RegionCommandType type = RegionCommandType::kFiner;
  int level = 0;
  double dx = 0.0, dy = 0.0;     ///< kPan [window widths]
  double x_m = 0.0, y_m = 0.0;   ///< kCentreAt [m]
};

/// How the haptic window and the navigation view are coloured (key C cycles the mode, L the
/// layer of the layer map; also in the panel and `explore --display`). Every mode is lit by
/// the same shading, colour × (ambient + Lambert), so the shape stays readable.
enum class DisplayMode : std::uint8_t {
  kColour = 0,  ///< the scan's colour per vertex (grey when the scene has none: the panel says so)
  kGrey,        ///< uniform neutral grey
  kLayerMap,    ///< one layer (MapLayer) through layer_colour_map(), its range in the panel
};

/// The layer a DisplayMode::kLayerMap shows.
enum class MapLayer : std::uint8_t {
  kTexture = 0,  ///< texture h [m], range symmetric about 0: ±(98th percentile of |h|)
  kMuD,          ///< μ_d [-], range [2nd, 98th] percentile
  kError,        ///< cross-check error [m], range [0, 98th percentile]
};

/// A display mode and, for the layer map, its layer.
struct DisplayChoice {
  DisplayMode mode = DisplayMode::kColour;
  MapLayer layer = MapLayer::kTexture;
  bool operator==(const DisplayChoice&) const = default;
};

/// The names of `explore --display` and the --script step `display`: "colour", "grey",
/// "texture", "mu_d", "error" (the last three: the layer map of that layer).
/// @param what the option's name for the message (e.g. "--display").
/// @throws hc::ConfigError "<what> '<text>' is unknown (expected colour, grey, texture, mu_d or
///         error)". Any thread.
DisplayChoice display_choice_from_string(const std::string& text, const std::string& what);
/// The name of a choice (inverse of display_choice_from_string; the layer only in kLayerMap).
std::string to_string(const DisplayChoice& choice);
/// The layer's name with its unit, for the panel: "texture h [mm]", "mu_d [-]",
/// "cross-check error [mm]".
std::string to_string(MapLayer layer);

/// The layer map's colour map, t ∈ [0, 1] (clamped; NaN gives the no-data grey 0.5, 0.5, 0.5)
/// → linear RGB in [0, 1]. Piecewise linear through five stops, chosen for this project (a
/// blue-to-red "cool to warm" ramp whose hue turns one way only, so the order of two colours
/// is unambiguous):
///   t = 0    (0.23, 0.18, 0.75) indigo
///   t = 0.25 (0.15, 0.55, 0.90) blue
///   t = 0.5  (0.20, 0.78, 0.55) green
///   t = 0.75 (0.95, 0.80, 0.20) yellow
///   t = 1    (0.85, 0.15, 0.10) red
/// Real-time: yes (no allocation).
Eigen::Vector3f layer_colour_map(double t);

/// The value range a layer map spreads over [0, 1] of layer_colour_map, from the finite samples
/// of `layer` (its unit: metres for texture and error, none for μ_d): see MapLayer for each
/// layer's rule (percentiles by nth_element on a copy: robust to a few spikes). hi is always
/// > lo: a constant layer value c (or no finite sample: c = 0) gives c ± ε for texture and μ_d
/// (c maps to the middle, t = 0.5) and [c, c + ε] for the error (c at the bottom), with
/// ε = max(1e-12, 1e-9·|c|) in the layer's unit.
struct LayerRange {
  double lo = 0.0, hi = 1.0;
  /// Position of v in the range, clamped to [0, 1]; NaN stays NaN.
  double t(double v) const;
};
LayerRange layer_range(const HeightField& layer, MapLayer which);

/// Surface-side settings the app applies by rebuilding the haptic surface (not servo commands).
struct SurfaceSettings {
  bool texture_enabled = true;          ///< false: render the envelope only (texture gain 0)
  double mu_s = 0.2;                    ///< static friction μ_s [-] ≥ 0 (constant over the surface)
  std::string friction_model = "paper"; ///< "paper" | "curvature"
};

/// Requests from the viewer to the app, all called on the UI thread; an empty function means
/// "not available" (the matching GUI control is disabled). They must return quickly: slow work
/// (the pipeline) belongs on another thread, and its result comes back through set_scene().
struct ViewerCallbacks {
  std::function<void(const RegionCommand&)> on_region;
  /// Re-scan the raw cloud with this orientation (model → grid rotation).
  std::function<void(const Eigen::Quaterniond&)> on_rescan;
  std::function<void(const SurfaceSettings&)> on_surface_settings;
  std::function<void(double volume)> on_audio_volume;  ///< [0, 1]
  /// Called once per frame before drawing (the app's session state machine runs here).
  std::function<void()> on_frame;
  /// A one-line status from the app (e.g. "re-scanning ..."), shown in the panel.
  std::function<std::string()> status;
};

/// Initial state and limits of the viewer.
struct ViewerOptions {
  int width_px = 1280;
  int height_px = 800;
  std::string title = "hapticloud explore";
  bool visible = true;               ///< false: hidden window (tests, --screenshot)
  bool show_panel = true;            ///< the ImGui panel
  bool show_help = false;            ///< the help overlay (toggle with H / F1)
  bool show_navigation = true;       ///< the navigation view (right-hand strip)
  bool vsync = true;
  double max_fps = 60.0;             ///< frame-rate cap (sleeps the UI thread) [Hz]; 0 = none
  bool stereo = false;               ///< red/cyan anaglyph (mono by default)
  DisplayChoice display;             ///< starting display mode (colour by default)
  double eye_separation = 0.03;      ///< eye separation / convergence distance [-], (0, 0.2]
  double field_of_view_deg = 35.0;   ///< vertical field of view of the main view [deg]
  /// Mouse drives the HIP: x, y under the cursor (on the plane of the HIP), wheel for z.
  bool mouse_drives_hip = false;
  double max_force_n = 8.0;          ///< force that draws the longest arrow [N]
  double max_stiffness_n_per_m = 2000.0;  ///< slider range of the stiffness (device frame)
  // Initial GUI values (the servo loop's own settings, shown in the panel).
  double stiffness_n_per_m = 800.0;
  double rho = 0.9;
  bool friction_enabled = true;
  SurfaceSettings surface;
  double audio_volume = 0.8;
  bool show_regions = false;         ///< the audio-region overlay (toggle with A)
};

/// An RGB image, 8 bits per channel, rows top to bottom.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgb;  ///< width·height·3 bytes
  std::uint8_t at(int x, int y, int channel) const {
    return rgb[(static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)) * 3 +
               static_cast<std::size_t>(channel)];
  }
};

/// Writes `image` as an 8-bit RGB PNG. @throws hc::InputError naming the file if it cannot be
/// written. Real-time: no.
void write_png(const Image& image, const std::string& path);

/// Frame timing measured by the viewer (steady clock, whole frame including swap).
/// Times exclude the frame-rate cap's sleep.
struct FrameStats {
  std::uint64_t frames = 0;
  double mean_frame_s = 0.0;
  double max_frame_s = 0.0;
  double last_frame_s = 0.0;
};

/// Pixel rectangle of a view inside the window (origin top-left, y down).
struct PixelRect {
  int x = 0, y = 0, width = 0, height = 0;
  bool contains(double px, double py) const {
    return px >= x && py >= y && px < x + width && py < y + height;
  }
};

class Viewer {
 public:
  /// Opens the window and the OpenGL 3.3 core context, compiles the shaders, sets up ImGui.
  /// @throws hc::ResourceError when GLFW cannot start (no display: name $DISPLAY and suggest
  ///         xvfb-run) or the context cannot be created; hc::ConfigError for options out of range.
  /// Real-time: no.
  Viewer(haptics::SharedState& shared, const ViewerOptions& options, ViewerCallbacks callbacks = {});
  ~Viewer();
  Viewer(const Viewer&) = delete;
  Viewer& operator=(const Viewer&) = delete;

  /// Hands a new scene to the viewer; it is meshed at the next frame. Thread-safe (any thread).
  void set_scene(std::shared_ptr<const DisplayScene> scene);

  /// One frame: events, on_frame, snapshot, draw, swap. @return false once the window was
  /// asked to close (close button, Esc, Q). Never blocks on the servo loop.
  bool frame();
  /// Draws one frame and returns its pixels (read before the swap).
  Image capture();

  /// The common path of keys, GUI, navigation clicks and device buttons.
  void issue(const RegionCommand& command);
  /// Device buttons newly pressed (bit mask, as ButtonEvent::pressed) issue
  /// bit 0 → finer, bit 1 → coarser, bit 2 → pan left, bit 3 → pan right. Every frame the
  /// viewer drains SharedState::button_events (it is that ring's one consumer) into this.
  void press_device_buttons(std::uint32_t pressed);
  /// Where the mouse drives the HIP [m, device frame] (mouse mode); false until the cursor has
  /// been over the main view.
  bool mouse_target(Eigen::Vector3d& device_m) const;
  /// What a left click at window pixel (x, y) does: in the navigation view, centre the window
  /// there (a kCentreAt command); in the orientation tool, start an arcball drag.
  void left_click(double x, double y);
  /// Mouse mode without a mouse (tests): the cursor at pixel (px, py) of the window.
  void set_cursor_for_test(double px, double py);

  /// The display mode (DisplayMode) and the layer map's layer; the meshes are recoloured at
  /// the next frame. Same as the keys C / L and the panel's Display section.
  void set_display(const DisplayChoice& choice);
  const DisplayChoice& display() const { return display_; }
  /// C: colour → grey → layer map → colour. L: the next layer (texture → μ_d → error), and the
  /// layer map on.
  void cycle_display_mode();
  void cycle_map_layer();
  /// What the panel says about the current display: empty, or why it differs from the choice
  /// (e.g. "this scene has no colour layer: drawn grey", "no cross-check error in this scene").
  const std::string& display_note() const { return display_note_; }
  /// The current layer map's range in the window (main view) and the overview (navigation
  /// view), in the layer's unit [m or -]; meaningful only in DisplayMode::kLayerMap with the
  /// layer present.
  const LayerRange& window_range() const { return window_range_; }
  const LayerRange& overview_range() const { return overview_range_; }

  /// The audio-region overlay (key A): each region's outline in its colour (region_colour), on
  /// top of the main view and the navigation view.
  void set_show_regions(bool on) { show_regions_ = on; }
  bool show_regions() const { return show_regions_; }
  /// How far the panel's widest row (a widget with its label) reached past the panel's inner
  /// right edge in the last frame that drew it [px]: > 0 means something was clipped; 0 when
  /// it fits or the panel is hidden. For tests of the layout.
  double panel_overflow_px() const { return panel_overflow_px_; }
  /// Radius of the proxy ball on screen [px] for a main view `view_height_px` high: 1.25 % of
  /// the height, at least 5 px, whatever the window's extent or the camera's zoom (the HIP's
  /// ball is 0.45 of it).
  static double proxy_ball_radius_px(int view_height_px);

  void set_stereo(bool on) { stereo_ = on; }
  bool stereo() const { return stereo_; }
  /// @param ratio eye separation / convergence distance, clamped to [0.001, 0.2].
  void set_eye_separation(double ratio);
  double eye_separation() const { return eye_separation_; }
  /// The orientation tool: the raw-cloud preview turned by the orientation (arcball with the
  /// left button, or set_orientation); on_rescan(orientation()) is what Enter / Re-scan send.
  void set_orienting(bool on) { orienting_ = on; }
  bool orienting() const { return orienting_; }
  void set_orientation(const Eigen::Quaterniond& q) { orientation_ = q.normalized(); }
  const Eigen::Quaterniond& orientation() const { return orientation_; }
  /// Orbit of the main camera about the window centre [deg]: yaw about the grid z axis, tilt
  /// away from looking straight down −z.
  void set_camera(double yaw_deg, double tilt_deg, double zoom = 1.0);

  /// Pixel (x right, y down, window pixels) of a grid-frame point in the main view, seen by
  /// eye −1 (left, red), 0 (mono) or +1 (right, cyan).
  Eigen::Vector2d project(const Eigen::Vector3d& grid_m, int eye = 0) const;
  /// Pixel of a grid-frame point (x, y used) in the navigation view.
  Eigen::Vector2d project_navigation(const Eigen::Vector3d& grid_m) const;
  PixelRect main_view() const;
  PixelRect navigation_view() const;
  /// The scene being drawn (null before the first set_scene() has been taken by a frame).
  std::shared_ptr<const DisplayScene> scene() const { return scene_; }
  /// The latest snapshot read.
  const haptics::Snapshot& snapshot() const { return snapshot_; }
  const FrameStats& frame_stats() const { return frame_stats_; }
  /// Quad count of the window mesh (triangles / 2).
  std::size_t mesh_quads() const;
  void request_close();

 private:
  struct Gpu;  // OpenGL objects (viewer.cpp)
  void take_pending_scene();
  void rebuild_scene_meshes();
  void handle_input();
  void draw_main(const PixelRect& view);
  void draw_navigation(const PixelRect& view);
  void draw_orientation(const PixelRect& view);
  void draw_gui();
  void update_plots();
  void send_servo_settings();
  Eigen::Matrix4d main_view_matrix(double eye_offset) const;
  Eigen::Matrix4d main_projection(const PixelRect& view, double eye_offset) const;
  Eigen::Matrix4d navigation_projection(const PixelRect& view) const;
  void render_frame();
  void present();
  double eye_offset_for(int eye) const;
  static void on_key(::GLFWwindow* w, int key, int scancode, int action, int mods);
  static void on_scroll(::GLFWwindow* w, double dx, double dy);
  static void on_mouse_button(::GLFWwindow* w, int button, int action, int mods);

  haptics::SharedState& shared_;
  ViewerOptions options_;
  ViewerCallbacks callbacks_;
  ::GLFWwindow* window_ = nullptr;
  std::unique_ptr<Gpu> gpu_;

  std::mutex pending_mutex_;
  std::shared_ptr<const DisplayScene> pending_;
  std::shared_ptr<const DisplayScene> scene_;

  haptics::Snapshot snapshot_{};
  FrameStats frame_stats_{};
  bool stereo_ = false;
  DisplayChoice display_;
  bool display_dirty_ = false;   // recolour the meshes at the next frame
  std::string display_note_;
  LayerRange window_range_, overview_range_;
  double eye_separation_ = 0.03;
  double yaw_deg_ = 0.0, tilt_deg_ = 0.0, zoom_ = 1.0;
  bool show_panel_ = true, show_help_ = false, show_navigation_ = true, show_regions_ = false;
  bool close_requested_ = false;
  double panel_overflow_px_ = 0.0;
  // The audio-region outline of the raster outline_source_ (recomputed when it changes).
  std::shared_ptr<const HeightField> outline_source_;
  std::vector<RegionSegment> outline_;
  bool outline_uploaded_ = false;  // regions_navigation holds outline_ at outline_z_m_
  double outline_z_m_ = 0.0;

  // Mouse.
  double cursor_x_ = -1.0, cursor_y_ = -1.0;
  bool cursor_override_ = false;
  bool orbiting_ = false;
  double orbit_from_x_ = 0.0, orbit_from_y_ = 0.0;
  double hip_device_z_m_ = 0.0;
  bool have_mouse_target_ = false;
  Eigen::Vector3d mouse_target_m_ = Eigen::Vector3d::Zero();

  // Orientation tool (arcball on the raw-cloud preview).
  bool orienting_ = false;
  bool arcball_active_ = false;
  Eigen::Vector2d arcball_from_px_ = Eigen::Vector2d::Zero();
  Eigen::Quaterniond orientation_ = Eigen::Quaterniond::Identity();
  Eigen::Quaterniond arcball_start_ = Eigen::Quaterniond::Identity();
  Eigen::Quaterniond scene_orientation_ = Eigen::Quaterniond::Identity();
  float typed_angles_deg_[3] = {0.0F, 0.0F, 0.0F};

  // GUI values.
  float stiffness_ = 800.0F, rho_ = 0.9F, volume_ = 0.8F, mu_s_ = 0.2F;
  bool friction_enabled_ = true, texture_enabled_ = true;
  int friction_model_ = 0;  // 0 paper, 1 curvature
  int gui_level_ = 0;

  // Live plots (ring buffers, newest at plot_head_ − 1).
  static constexpr int kPlotLength = 240;
  float force_plot_[kPlotLength] = {};
  float rate_plot_[kPlotLength] = {};  // mean servo tick period per frame [us]
  int plot_head_ = 0;
  std::uint64_t last_ticks_ = 0;
  double last_plot_time_s_ = 0.0;  // servo clock time of the snapshot at last_ticks_
  double last_frame_start_s_ = 0.0;
};

/// Arcball (Shoemake, "ARCBALL", Graphics Interface 1992): the rotation that takes the point of
/// the unit sphere under pixel `from_px` to the one under `to_px`; the sphere fills the smaller
/// side of `view` (pixels, y down), points outside it lie on its rim. Eye frame (x right, y up,
/// z towards the viewer), which is the grid frame in the orientation tool. Real-time: yes.
Eigen::Quaterniond arcball_rotation(const PixelRect& view, const Eigen::Vector2d& from_px, const Eigen::Vector2d& to_px);

/// The controls, one line each (the help overlay shows them; the README lists the same).
const std::vector<std::string>& controls_help();

/// Off-axis (asymmetric) perspective frustum for one eye of a stereo pair whose eyes sit at
/// ±separation/2 along the camera's x axis, with parallel view axes and the zero-parallax plane
/// at `convergence` (OpenGL clip conventions, right-handed eye space looking down −z).
/// eye_offset = −separation/2 (left eye) or +separation/2 (right eye), same units as the
/// distances; 0 gives the ordinary symmetric frustum. Source: the parallel-axis asymmetric
/// frustum method (Bourke, "Calculating stereo pairs"). Real-time: yes.
Eigen::Matrix4d off_axis_projection(double fov_y_rad, double aspect, double near, double far,
                                    double convergence, double eye_offset);

}  // namespace hc::viewer
