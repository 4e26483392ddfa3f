// hapticloud's Python API (issue 17): the compiled part, `hapticloud._hapticloud`. The package's
// __init__.py re-exports it with the dict-config convenience. Every array is in SI units; grids
// are (rows, cols) with row 0 = the smallest y (the scene contract, docs/architecture.md).

#include "hc/common/bilinear_surface.hpp"
#include "hc/common/error.hpp"
#include "hc/common/scene.hpp"
#include "hc/pipeline/config.hpp"
#include "hc/pipeline/lod.hpp"
#include "hc/pipeline/lod_report.hpp"
#include "hc/session/level_timing.hpp"
#include "hc/pipeline/run.hpp"
#include "hc/pipeline/scene_io.hpp"
#include "hc/session/touch_session.hpp"

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <cmath>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace py = pybind11;

namespace {

using SceneRef = std::shared_ptr<hc::Scene>;

// A read-only, zero-copy array over `data` (C order, `shape`), whose base keeps `owner` (the
// scene) alive for as long as the array exists.
template <class T>
py::array_t<T> readonly_view(const T* data, std::vector<py::ssize_t> shape, std::shared_ptr<const void> owner) {
  using Owner = std::shared_ptr<const void>;
  const py::capsule keep(new Owner(std::move(owner)), [](void* p) { delete static_cast<Owner*>(p); });
  py::array_t<T> a(std::move(shape), data, keep);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

// A read-only float32 (rows, cols) view of `field`, kept alive by `owner` (the scene).
py::array_t<float> view(const hc::HeightField& field, std::shared_ptr<const void> owner) {
  return readonly_view(field.data(), {field.rows(), field.cols()}, owner);
}

py::dict layers_of(const SceneRef& s) {
  py::dict d;
  const hc::SceneLayers& l = s->layers;
  const std::pair<const char*, const hc::HeightField*> all[] = {
      {"depth", &l.depth}, {"envelope", &l.envelope},     {"texture", &l.texture},     {"mu_d", &l.mu_d},
      {"mu_s", &l.mu_s},   {"cell_error", &l.cell_error}, {"region_id", &l.region_id}, {"intensity", &l.intensity}};
  for (const auto& [name, f] : all)
    if (f->rows() > 0) d[name] = view(*f, s);
  return d;
}

py::object colour_of(const SceneRef& s) {
  const auto& c = s->layers.colour_rgb8;
  if (c.empty()) return py::none();
  return readonly_view(c.data(), {s->geometry.rows, s->geometry.cols, 3}, s);
}

using WindowRef = std::shared_ptr<const hc::pipeline::LodWindowLayers>;

// A window of stored levels as a dict of read-only views kept alive by the window.
py::dict window_dict(const WindowRef& w, double cell_size_m) {
  py::dict d;
  d["level"] = w->level;
  d["row0"] = w->row0;
  d["col0"] = w->col0;
  d["x0_m"] = w->depth_m.geometry().x0_m;
  d["y0_m"] = w->depth_m.geometry().y0_m;
  d["cell_size_m"] = cell_size_m;
  const std::pair<const char*, const hc::HeightField*> all[] = {{"depth", &w->depth_m}, {"envelope", &w->envelope_m},
                                                                {"texture", &w->texture_m}, {"mu_d", &w->mu_d},
                                                                {"mu_s", &w->mu_s}, {"cell_error", &w->cell_error_m}};
  py::dict layers;
  for (const auto& [name, f] : all)
    if (f->rows() > 0) layers[name] = view(*f, w);
  d["layers"] = layers;
  d["colour"] = w->colour_rgb8.empty()
                    ? py::object(py::none())
                    : py::object(readonly_view(w->colour_rgb8.data(), {w->depth_m.rows(), w->depth_m.cols(), 3}, w));
  return d;
}

py::array_t<double> matrix_of(const Eigen::Affine3d& t) {
  py::array_t<double> a({4, 4});
  auto m = a.mutable_unchecked<2>();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = t.matrix()(r, c);
  return a;
}

SceneRef run_config(const hc::pipeline::RunConfig& cfg, const std::optional<std::filesystem::path>& out) {
  if (!out) return std::make_shared<hc::Scene>(hc::pipeline::build_scene(cfg).scene);
  (void)hc::pipeline::run_pipeline(cfg, *out);
  return std::make_shared<hc::Scene>(hc::pipeline::load_scene(*out / "scene"));
}

// A (n, 3) float64 array from the 3-vectors `get(row)` of the trace.
template <class Get>
py::array_t<double> columns3(const std::vector<hc::haptics::TickRecord>& t, Get get) {
  py::array_t<double> a({static_cast<py::ssize_t>(t.size()), py::ssize_t{3}});
  auto m = a.mutable_unchecked<2>();
  for (std::size_t i = 0; i < t.size(); ++i) {
    const hc::haptics::Vec3& v = get(t[i]);
    m(static_cast<py::ssize_t>(i), 0) = v.x;
    m(static_cast<py::ssize_t>(i), 1) = v.y;
    m(static_cast<py::ssize_t>(i), 2) = v.z;
  }
  return a;
}

}  // namespace

PYBIND11_MODULE(_hapticloud, m) {
  m.doc() = "hapticloud: Monge surfaces from scans, their haptic layers, cross-check and scripted touch sessions";
  static py::exception<hc::Error> error(m, "Error");
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const hc::Error& e) {
      error(e.what());
    }
  });

  py::class_<hc::Scene, SceneRef>(m, "Scene",
                                  "A scene: a Monge grid z = f(x, y) with its layers, in the grid frame (metres; "
                                  "larger z nearer the viewer). Arrays are read-only views into the scene.")
      .def_property_readonly("rows", [](const hc::Scene& s) { return s.geometry.rows; }, "grid rows (along y)")
      .def_property_readonly("cols", [](const hc::Scene& s) { return s.geometry.cols; }, "grid columns (along x)")
      .def_property_readonly("cell_size_m", [](const hc::Scene& s) { return s.geometry.cell_size_m; }, "node spacing [m]")
      .def_property_readonly("x0_m", [](const hc::Scene& s) { return s.geometry.x0_m; }, "x of column 0 [m], grid frame")
      .def_property_readonly("y0_m", [](const hc::Scene& s) { return s.geometry.y0_m; }, "y of row 0 [m], grid frame")
      .def_property_readonly("model_to_grid", [](const hc::Scene& s) { return matrix_of(s.model_to_grid); },
                             "4x4 float64: scan file coordinates (file units) -> grid frame [m]")
      .def_property_readonly("layers", [](const SceneRef& s) { return layers_of(s); },
                             "dict name -> float32 array (rows, cols), NaN = no data: depth [m] (grid frame z), "
                             "envelope [m], texture [m], mu_d [-], mu_s [-], cell_error [m], region_id, intensity; "
                             "only the layers the scene has")
      .def_property_readonly("colour", [](const SceneRef& s) { return colour_of(s); },
                             "uint8 array (rows, cols, 3), R G B per node, or None")
      .def_property_readonly("units", [](const hc::Scene& s) { return s.provenance.units; }, "the scan's file units")
      .def_property_readonly("crs", [](const hc::Scene& s) { return s.provenance.crs; }, "the scan's CRS text, or ''")
      .def("__repr__", [](const hc::Scene& s) {
        return "<hapticloud.Scene " + std::to_string(s.geometry.rows) + " x " + std::to_string(s.geometry.cols) +
               " cells of " + std::to_string(s.geometry.cell_size_m * 1e3) + " mm>";
      });

  using hc::pipeline::LodPyramid;
  py::class_<LodPyramid, std::shared_ptr<LodPyramid>>(
      m, "Levels",
      "The levels of detail of a tiled scene, read from its files window by window (open_levels). Windows are "
      "cached under the scene's lod.memory_budget_mb.")
      .def_property_readonly("level_count", &LodPyramid::level_count, "number of levels (0 = finest)")
      .def(
          "geometry",
          [](const LodPyramid& p, int level) {
            const hc::GridGeometry& g = p.geometry(level);
            py::dict d;
            d["rows"] = g.rows;
            d["cols"] = g.cols;
            d["cell_size_m"] = g.cell_size_m;
            d["x0_m"] = g.x0_m;
            d["y0_m"] = g.y0_m;
            return d;
          },
          py::arg("level"), "dict rows, cols, cell_size_m [m], x0_m, y0_m [m] (grid frame) of a level")
      .def(
          "window",
          [](LodPyramid& p, int level, int row0, int col0, int rows, int cols) {
            WindowRef w;
            {
              py::gil_scoped_release release;
              w = p.window(level, row0, col0, rows, cols);
            }
            return window_dict(w, p.geometry(level).cell_size_m);
          },
          py::arg("level"), py::arg("row0"), py::arg("col0"), py::arg("rows"), py::arg("cols"),
          "rows x cols samples of a level from (row0, col0), clamped into the level (as the haptic window is): a "
          "dict with level, row0, col0 (where it landed), x0_m, y0_m, cell_size_m [m], layers (name -> read-only "
          "float32 (rows, cols): depth, envelope, texture [m], mu_d, mu_s [-], cell_error [m], those stored; NaN = "
          "no data) and colour (uint8 (rows, cols, 3) or None). Reads only the tiles the window overlaps.")
      .def_property_readonly("tiles_read", &LodPyramid::tiles_read, "tiles decoded from the files so far");
  m.def(
      "open_levels",
      [](const std::filesystem::path& p, std::optional<double> memory_budget_mb) {
        const hc::Scene header = hc::pipeline::load_scene(p, false);
        hc::LodOptions lod = header.lod;
        if (memory_budget_mb) lod.memory_budget_mb = *memory_budget_mb;
        return LodPyramid::open_stored(p, lod);
      },
      py::arg("path"), py::arg("memory_budget_mb") = py::none(), py::call_guard<py::gil_scoped_release>(),
      "Opens the stored levels of a tiled scene folder (scene format 3: `hapticloud run` with scale.scene_tiles, "
      "docs/scale.md) without loading its layers: a Levels object whose window() reads only the tiles it needs. "
      "Raises hapticloud.Error for a folder that stores no levels.");

  m.def("load_scene", [](const std::filesystem::path& p) { return std::make_shared<hc::Scene>(hc::pipeline::load_scene(p)); },
        py::arg("path"), py::call_guard<py::gil_scoped_release>(),
        "Loads a scene folder written by `hapticloud run` (DIR/scene). Raises hapticloud.Error.");

  m.def(
      "_run_file",
      [](const std::filesystem::path& config, const std::optional<std::filesystem::path>& out, const std::vector<std::string>& sets) {
        return run_config(hc::pipeline::load_run_config(config, sets), out);
      },
      py::arg("config"), py::arg("out") = py::none(), py::arg("sets") = std::vector<std::string>{},
      py::call_guard<py::gil_scoped_release>());
  m.def(
      "_run_text",
      [](const std::string& text, const std::filesystem::path& origin, const std::optional<std::filesystem::path>& out,
         const std::vector<std::string>& sets) { return run_config(hc::pipeline::parse_run_config(text, origin, sets), out); },
      py::arg("text"), py::arg("origin"), py::arg("out") = py::none(), py::arg("sets") = std::vector<std::string>{},
      py::call_guard<py::gil_scoped_release>());

  m.def(
      "sample",
      [](const hc::Scene& s, py::array_t<double, py::array::c_style | py::array::forcecast> x,
         py::array_t<double, py::array::c_style | py::array::forcecast> y) {
        if (x.size() != y.size()) throw py::value_error("sample: x and y differ in size");
        const hc::BilinearSurface surface(hc::HeightFieldView::of(s.layers.depth));
        py::array_t<double> z(x.size()), gx(x.size()), gy(x.size());
        py::array_t<double> normal({static_cast<py::ssize_t>(x.size()), static_cast<py::ssize_t>(3)});
        auto zo = z.mutable_unchecked<1>(), gxo = gx.mutable_unchecked<1>(), gyo = gy.mutable_unchecked<1>();
        auto no = normal.mutable_unchecked<2>();
        const double* xp = x.data();
        const double* yp = y.data();
        for (py::ssize_t i = 0; i < x.size(); ++i) {
          const hc::SurfaceSample r = surface.sample(xp[i], yp[i]);
          zo(i) = r.z_m;
          gxo(i) = r.dz_dx;
          gyo(i) = r.dz_dy;
          // The Monge surface's upward unit normal (-f_x, -f_y, 1) / |.|.
          const double len = std::sqrt(r.dz_dx * r.dz_dx + r.dz_dy * r.dz_dy + 1.0);
          no(i, 0) = -r.dz_dx / len;
          no(i, 1) = -r.dz_dy / len;
          no(i, 2) = 1.0 / len;
        }
        return py::make_tuple(z, gx, gy, normal);
      },
      py::arg("scene"), py::arg("x"), py::arg("y"),
      "Bilinear height, gradient and normal of the depth layer at grid-frame points x, y [m] (array-likes of the "
      "same size n, read flattened): returns (z [m], dz/dx [-], dz/dy [-], normal) with z and the slopes 1-D float64 "
      "arrays (n,) and normal (n, 3), the upward unit normal (-dz/dx, -dz/dy, 1)/|.| in the grid frame; NaN where a "
      "cell corner has no data; outside the grid the border value continues (zero slope across it).");

  m.def(
      "touch",
      [](const hc::Scene& s, const std::string& path, double seconds, double rate_hz, double stiffness_n_per_m,
         bool friction, double texture_gain) {
        hc::session::TouchSessionOptions o;
        o.path = path;
        o.seconds = seconds;
        o.rate_hz = rate_hz;
        o.stiffness_n_per_m = stiffness_n_per_m;
        o.friction = friction;
        o.texture_gain = texture_gain;
        hc::session::TouchSessionResult r;
        {
          py::gil_scoped_release release;
          r = hc::session::run_touch_session(s, o);
        }
        const auto& t = r.trace;
        py::array_t<double> time(static_cast<py::ssize_t>(t.size())), mu_d(static_cast<py::ssize_t>(t.size()));
        py::array_t<bool> contact(static_cast<py::ssize_t>(t.size()));
        auto tm = time.mutable_unchecked<1>();
        auto mu = mu_d.mutable_unchecked<1>();
        auto cm = contact.mutable_unchecked<1>();
        for (std::size_t i = 0; i < t.size(); ++i) {
          tm(static_cast<py::ssize_t>(i)) = t[i].t_s;
          mu(static_cast<py::ssize_t>(i)) = t[i].mu_d;
          cm(static_cast<py::ssize_t>(i)) = t[i].in_contact;
        }
        py::dict d;
        d["t_s"] = time;
        d["hip_m"] = columns3(t, [](const hc::haptics::TickRecord& k) -> const hc::haptics::Vec3& { return k.hip_m; });
        d["proxy_m"] = columns3(t, [](const hc::haptics::TickRecord& k) -> const hc::haptics::Vec3& { return k.proxy_m; });
        d["force_n"] = columns3(t, [](const hc::haptics::TickRecord& k) -> const hc::haptics::Vec3& { return k.force_n; });
        d["in_contact"] = contact;
        d["mu_d"] = mu_d;
        d["surface_z_m"] = py::array_t<double>(static_cast<py::ssize_t>(r.surface_z_m.size()), r.surface_z_m.data());
        return d;
      },
      py::arg("scene"), py::arg("path") = "raster", py::arg("seconds") = 2.0, py::arg("rate_hz") = 1000.0,
      py::arg("stiffness_n_per_m") = 800.0, py::arg("friction") = true, py::arg("texture_gain") = 1.0,
      "A scripted, headless haptic session on the scene (as `hapticloud touch`, on a simulated clock): a simulated "
      "device follows `path` (raster, circle, line, press-slide, hold) through a virtual hand for `seconds`. Returns "
      "a dict of per-tick arrays, grid frame, SI: t_s (n,), hip_m (n,3), proxy_m (n,3), force_n (n,3) (force on the "
      "hand, grid axes), in_contact (n,), mu_d (n,), surface_z_m (n,) (rendered height under the proxy).");

  // levels(): the speed-against-error table of `hapticloud levels`. The cross-check's points
  // (cross_check true; levels() in __init__.py refuses a config with it false): `config`'s (a
  // parsed run config: its scan read and filtered), else, for
  // a Levels object or a loaded Scene (Scene::loaded_from) whose folder stores points_sample.bin
  // (a tiled run's strided sample of its filtered points, lod_report.hpp), that sample, as
  // `hapticloud levels` takes it; else none.
  // servo_ticks > 0 times the servo. A Levels object (open_levels: a tiled scene's stored
  // levels) goes as it is: nothing is built, a large level is read a window at a time
  // (level_table); a Scene is copied into a pyramid.
  const auto levels = [](const std::variant<SceneRef, std::shared_ptr<LodPyramid>>& source,
                         const std::optional<hc::pipeline::RunConfig>& config, int servo_ticks, bool cross_check) {
    if (servo_ticks < 0 || (servo_ticks > 0 && servo_ticks < 10)) {
      throw hc::ConfigError("levels: servo_ticks " + std::to_string(servo_ticks) + " (expected 0: no timing, or >= 10)");
    }
    std::vector<hc::pipeline::LevelRow> rows;
    const char* points_from = nullptr;  // the rows' "points_from"
    {
      py::gil_scoped_release release;  // no Python object is touched in here
      std::shared_ptr<LodPyramid> pyramid;
      hc::LodOptions lod;
      std::filesystem::path folder;  // the scene's folder, where its points_sample.bin would be
      if (const auto* stored = std::get_if<std::shared_ptr<LodPyramid>>(&source)) {
        pyramid = *stored;
        lod = pyramid->options();
        folder = pyramid->stored_dir();
      } else {
        hc::Scene copy = *std::get<SceneRef>(source);
        const auto layer_options = copy.layer_options;
        lod = copy.lod;
        folder = copy.loaded_from;  // empty for a scene built in memory (run() without out)
        pyramid = hc::pipeline::LodPyramid::from_scene(std::move(copy), layer_options, lod);
      }
      std::optional<hc::pipeline::Cloud> points;
      std::uint64_t points_represent = 0;
      if (config) {
        hc::pipeline::check_in_core_fits(*config, hc::pipeline::memory_limit_bytes(),
                                         "leave config out to cross-check against the points sample the folder of a "
                                         "tiled run's scene stores (points_sample.bin), or pass cross_check=False");
        points = hc::pipeline::prepare_points(*config);
        points_from = "scan";
      } else if (cross_check && !folder.empty()) {
        if (auto sample = hc::pipeline::read_level_point_sample(folder)) {
          points_represent = sample->represents;  // every point: the whole set (level_table)
          points = std::move(sample->points);
          points_from = hc::pipeline::kLevelPointSampleFile;
        }
      }
      hc::pipeline::LevelTableOptions o;
      o.cross_check = points.has_value();
      o.sample_points = lod.report_sample_points;
      o.points_represent = points_represent;  // a stored sample of more points: (a) from it, no support
      rows = hc::pipeline::level_table(pyramid, points ? &*points : nullptr, o);
      if (servo_ticks > 0) hc::session::time_levels(pyramid, rows, servo_ticks);
    }
    py::list out;
    const py::object none = py::none();
    for (const auto& r : rows) {
      py::dict d;
      d["level"] = r.level;
      d["rows"] = r.rows;
      d["cols"] = r.cols;
      d["cell_size_m"] = r.cell_size_m;
      d["valid_cells"] = r.valid_cells;
      d["build_s"] = r.build_seconds;
      d["stored"] = r.stored;
      d["points_from"] = points_from ? py::object(py::str(points_from)) : none;
      if (r.point_vertical) {
        d["rms_m"] = 1e-3 * r.point_vertical->rms_mm;
        d["p95_m"] = 1e-3 * r.point_vertical->p95_mm;
        d["max_m"] = 1e-3 * r.point_vertical->max_mm;
        d["points_checked"] = r.point_vertical->count;
        d["supported_fraction"] = r.support_measured ? py::object(py::float_(r.supported_fraction)) : none;
        d["points_sampled"] = r.points_checked;
        d["points_total"] = r.points_total;
        d["sampled"] = r.points_checked < r.points_total;
      } else {
        for (const char* k : {"rms_m", "p95_m", "max_m", "points_checked", "supported_fraction", "points_sampled",
                              "points_total", "sampled"}) {
          d[k] = none;
        }
      }
      d["mu_d_at_min_fraction"] = r.mu_d ? py::object(py::float_(r.mu_d->at_min_fraction())) : none;
      d["mu_d_at_max_fraction"] = r.mu_d ? py::object(py::float_(r.mu_d->at_max_fraction())) : none;
      d["tick_p50_s"] = r.timed ? py::object(py::float_(1e-9 * r.tick_p50_ns)) : none;
      d["tick_p99_s"] = r.timed ? py::object(py::float_(1e-9 * r.tick_p99_ns)) : none;
      d["switch_s"] = r.timed ? py::object(py::float_(1e-3 * r.switch_ms)) : none;
      out.append(d);
    }
    return out;
  };
  using LevelsSource = std::variant<SceneRef, std::shared_ptr<LodPyramid>>;
  m.def(
      "_levels_file",
      [levels](const LevelsSource& s, const std::optional<std::string>& config_path, int servo_ticks, bool cross_check) {
        std::optional<hc::pipeline::RunConfig> config;
        if (config_path) config = hc::pipeline::load_run_config(*config_path);
        return levels(s, config, servo_ticks, cross_check);
      },
      py::arg("scene"), py::arg("config"), py::arg("servo_ticks"), py::arg("cross_check"));
  m.def(
      "_levels_text",
      [levels](const LevelsSource& s, const std::string& text, const std::string& origin, int servo_ticks, bool cross_check) {
        return levels(s, hc::pipeline::parse_run_config(text, origin), servo_ticks, cross_check);
      },
      py::arg("scene"), py::arg("text"), py::arg("origin"), py::arg("servo_ticks"), py::arg("cross_check"));
}
