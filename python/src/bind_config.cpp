// The command-line tool's TOML configurations: ConfiguredRun and load_config,
// with ConfigError and OutputDirError. The only file of the module that
// needs otfp_app (the tool's configuration parser, run driver and
// output-directory rules); the rest is built on the library alone.
#include "common.hpp"

#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "otfp_app/config.hpp"
#include "otfp_app/out_dir.hpp"
#include "otfp_app/simulation.hpp"

#include "bindings.hpp"

namespace otfp::python {

namespace {

// ConfiguredRun.run's out_dir refused (an earlier run there, a held lock, not
// a directory): the command-line tool's rules, raised as a ValueError.
class OutputDirError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Control characters as escapes: a path with a newline stays a one-line message.
std::string escaped(const std::string& s) {
  std::string out;
  for (const char ch : s) {
    const auto u = static_cast<unsigned char>(ch);
    if (u < 0x20 || u == 0x7f) {
      static const char hex[] = "0123456789abcdef";
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    } else {
      out += ch;
    }
  }
  return out;
}

py::dict json_to_dict(const nlohmann::json& j) {
  py::module_ json = py::module_::import("json");
  return json.attr("loads")(j.dump()).cast<py::dict>();
}

}  // namespace

void bind_config(py::module_& m) {
  py::register_exception<app::ConfigError>(m, "ConfigError", PyExc_ValueError);
  py::register_exception<OutputDirError>(m, "OutputDirError", PyExc_ValueError);

  // ---- the command-line tool's configurations
  // run() steps the configuration's own Simulation: runs from several
  // threads take turns (the rest reads what the constructor fixed).
  using PyConfiguredRun = Locked<app::ConfiguredRun>;
  py::class_<PyConfiguredRun>(m, "ConfiguredRun", "A TOML configuration of `otfp run`, with its derived numbers.")
      .def_property_readonly("description",
                             [](const PyConfiguredRun& r) { return json_to_dict(r.object->describe()); },
                             "{'config': the resolved keys, 'derived': dt, n_steps, M_inf, ...}")
      .def_property_readonly("dt", [](const PyConfiguredRun& r) { return r.object->derived().dt; })
      .def_property_readonly("n_steps", [](const PyConfiguredRun& r) { return r.object->derived().n_steps; })
      .def_property_readonly("t_end", [](const PyConfiguredRun& r) { return r.object->config().run.t_end; })
      .def_property_readonly("M_inf", [](const PyConfiguredRun& r) { return r.object->derived().M_inf; })
      .def_property_readonly("center", [](const PyConfiguredRun& r) { return r.object->derived().center; })
      .def_property_readonly("domain", [](const PyConfiguredRun& r) { return mutable_domain(r.object->domain_ptr()); })
      .def("make_simulation",
           [](const PyConfiguredRun& r) { return std::make_unique<PySimulation>(r.object->make_simulation()); },
           "A started Simulation as `otfp run` builds it: advance_to(k * dt) reproduces the CLI's steps bit for bit.")
      .def("run",
           [](PyConfiguredRun& r, const std::filesystem::path& out_dir, bool progress, bool overwrite) {
             auto held = r.lock.hold();
             app::RunOptions o;
             o.out_dir = out_dir;
             o.progress = progress;
             o.keep_series = false;
             app::RunResult res;
             {
               py::gil_scoped_release release;
               // The command-line tool's rules: the directory locked for the
               // whole run, an earlier run's refused unless overwrite=True.
               app::OutputLock lock;
               if (!out_dir.empty())
                 if (const std::string why =
                         app::prepare_out_dir(out_dir, /*resume=*/false, overwrite, lock, "overwrite=True");
                     !why.empty())
                   throw OutputDirError("out_dir = \"" + escaped(out_dir.string()) + "\": " + escaped(why));
               res = r.object->run(o);
             }
             py::dict d;
             d["status"] = res.status;
             d["exit_code"] = res.exit_code;
             d["error"] = res.error;
             d["summary"] = json_to_dict(res.summary);
             return d;
           },
           py::arg("out_dir") = std::filesystem::path(), py::arg("progress") = false, py::kw_only(),
           py::arg("overwrite") = false,
           "The whole run as `otfp run CONFIG --out out_dir [--overwrite]` (nothing written when out_dir is empty). "
           "OutputDirError (a ValueError) when out_dir holds an earlier run (unless overwrite=True) or another "
           "run holds its lock.");
  m.def("load_config",
        [](const std::filesystem::path& path, const std::vector<std::string>& overrides) {
          return std::make_unique<PyConfiguredRun>(
              std::make_unique<app::ConfiguredRun>(app::parse_config_file(path, overrides)));
        },
        py::arg("path"), py::arg("overrides") = std::vector<std::string>{},
        "Reads a TOML configuration (overrides: 'key=value' as --set) and derives (36)-(40); ConfigError names the key.");
}

}  // namespace otfp::python
