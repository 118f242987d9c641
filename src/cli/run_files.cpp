// The files of a run (docs/outputs.md): rows, snapshots, summaries.
#include <fmt/format.h>

#include "otfp/diagnostics.hpp"
#include "otfp/particle_io.hpp"
#include "otfp/surface.hpp"
#include "otfp/vtk.hpp"
#include "run_parts.hpp"

namespace otfp::app::detail {

RunFiles::RunFiles(const ConfiguredRun& run, const otfp::Simulation& sim, std::filesystem::path out,
                   bool kill_summary, Summary summary)
    : run_(run),
      sim_(sim),
      out_(std::move(out)),
      root_(sim.root_process()),
      kill_summary_(kill_summary),
      summary_(std::move(summary)) {}

void RunFiles::create(const std::string& series_header, const std::string& timing_header) {
  if (!active() || !root_) return;
  std::filesystem::create_directories(out_);
  series_ = AppendFile(out_ / "series.csv", series_header);
  timing_ = AppendFile(out_ / "timing.csv", timing_header);
  write_file_atomic(out_ / "config.toml", to_toml(run_.config()));
  arm_kill_summary(StepRecord{}, false);
  write_domain_surface();
  write_file_atomic(out_ / "summary.json", summary_("running", "", StepRecord{}).dump(2) + "\n");
}

void RunFiles::reopen(const std::string& series_text, const std::string& timing_text, const StepRecord& last) {
  if (!root_) return;
  series_ = AppendFile(out_ / "series.csv", series_text);
  timing_ = AppendFile(out_ / "timing.csv", timing_text);
  arm_kill_summary(last, true);
  write_file_atomic(out_ / "summary.json", summary_("running", "", last).dump(2) + "\n");
}

void RunFiles::append(const std::string& series_line, const std::string& timing_line, const StepRecord& r,
                      bool snapshot_due, const std::vector<std::int32_t>& region) {
  if (!active()) return;
  // A distributed snapshot first: its collectives (the density over every
  // rank's blobs) come before any write that might fail on one rank.
  if (sim_.distributed() && snapshot_due) snapshot(r, region);
  if (!root_) return;
  // A row is in both files or in neither (a full disk fails either write).
  const std::uint64_t series_size = series_.size();
  series_.append(series_line);
  try {
    timing_.append(timing_line);
  } catch (...) {
    series_.truncate(series_size);
    throw;
  }
  if (snapshot_due && !sim_.distributed()) snapshot(r, region);
}

void RunFiles::snapshot(const StepRecord& r, const std::vector<std::int32_t>& region) {
  if (last_snapshot == r.step) return;
  if (sim_.distributed()) {
    distributed_snapshot(r, region);
    return;
  }
  const ParticleSet& particles = sim_.particles();
  for (const Vec3& x : particles.positions())
    if (!x.allFinite()) throw RunError(fmt::format("non-finite particle position at step {}", r.step));
  const std::string name = fmt::format("particles_{:05d}.vtp", r.step);
  // The blob density (29) at each particle (images across mirrored walls not included).
  const std::vector<double> rho = sim_.particle_density(run_.config().solver.kernel_tolerance);
  write_file_atomic(out_ / name, vtp_document(particles, r.t, region, rho));
  snapshots.emplace_back(r.t, name);
  write_file_atomic(out_ / "particles.pvd", pvd_document(snapshots));
  last_snapshot = r.step;
}

// A distributed run's snapshot: each rank writes its particles as a piece
// (the blob density at them summed over every rank's blobs), rank 0 the
// .pvtp that joins them and the .pvd.
void RunFiles::distributed_snapshot(const StepRecord& r, const std::vector<std::int32_t>& region) {
  const ParticleSet& particles = sim_.particles();
  bool finite = true;
  for (const Vec3& x : particles.positions()) finite = finite && x.allFinite();
  if (sim_.any_process(!finite)) throw RunError(fmt::format("non-finite particle position at step {}", r.step));
  const std::vector<double> rho = sim_.particle_density(run_.config().solver.kernel_tolerance);
  const std::string base = fmt::format("particles_{:05d}", r.step);
  write_file_atomic(out_ / fmt::format("{}_{}.vtp", base, sim_.process_rank()),
                    vtp_document(particles, r.t, region, rho));
  if (root_) {
    std::vector<std::string> pieces;
    for (int k = 0; k < sim_.process_count(); ++k) pieces.push_back(fmt::format("{}_{}.vtp", base, k));
    write_file_atomic(out_ / (base + ".pvtp"), pvtp_document(pieces));
    snapshots.emplace_back(r.t, base + ".pvtp");
    write_file_atomic(out_ / "particles.pvd", pvd_document(snapshots));
  }
  last_snapshot = r.step;
}

void RunFiles::arm_kill_summary(const StepRecord& r, bool have_row) {
  if (!active() || !kill_summary_ || !root_) return;
  const std::string why =
      have_row ? fmt::format("stopped by a second signal during a step after step {} (t = {}); the files are "
                             "complete up to step {} at least; continue from the last checkpoint, if one was "
                             "written, with: otfp run --resume {}",
                             r.step, r.t, r.step, out_.string())
               : std::string("stopped by a second signal before the first row was written");
  set_kill_time_summary(out_ / "summary.json", summary_("interrupted", why, r).dump(2) + "\n");
}

void RunFiles::rearm_kill_summary(const StepRecord& r) {
  const auto now = Clock::now();
  if (r.step == 0 || now - kill_summary_time_ >= std::chrono::milliseconds(500)) {
    kill_summary_time_ = now;
    arm_kill_summary(r, true);
  }
}

void RunFiles::write_checkpoint(const nlohmann::json& driver) {
  sim_.save_checkpoint(out_ / "checkpoint.bin", driver.dump());
}

void RunFiles::write_summary(const nlohmann::json& summary) {
  if (!root_) return;
  std::filesystem::create_directories(out_);
  write_file_atomic(out_ / "summary.json", summary.dump(2) + "\n");
}

void RunFiles::write_final_particles(const std::vector<std::int32_t>& region) {
  // Final particles as CSV (widths for histograms, positions for profiles).
  if (!active()) return;
  if (!sim_.distributed()) {
    write_file_atomic(out_ / "particles_final.csv", particles_csv(sim_.particles(), region));
    return;
  }
  // Every rank's, in id order, with their regions (collective).
  const ParticleSet all = sim_.gathered_particles();
  if (!root_) return;
  std::vector<std::int32_t> regions;
  measure_state(sim_.domain(), sim_.buffer(), all, Vec3::Zero(), sim_.time(), &regions);
  write_file_atomic(out_ / "particles_final.csv", particles_csv(all, regions));
}

void RunFiles::write_failed_particles(const Derived& d, double t) noexcept {
  // Not part of particles.pvd.
  if (!active()) return;
  try {
    bool finite = true;
    for (const Vec3& x : sim_.particles().positions()) finite = finite && x.allFinite();
    if (finite) {
      std::vector<std::int32_t> flags;
      // This rank's own measure (no collective on the way out of a failure).
      measure_state(sim_.domain(), sim_.buffer(), sim_.particles(), d.center, t, &flags);
      std::filesystem::create_directories(out_);
      const std::string name = sim_.distributed() ? fmt::format("particles_failed_{}.vtp", sim_.process_rank())
                                                  : std::string("particles_failed.vtp");
      write_file_atomic(out_ / name, vtp_document(sim_.particles(), t, flags));
    }
  } catch (const std::exception&) {
    // Best effort: the error being reported matters more.
  }
}

// domain.vtp: the boundary of Omega and, where there is one, the outer
// surface of the buffer over the Dirichlet patches (its cells carry patch
// id + the number of patches). A coarse display mesh in a file of its own:
// listed in particles.pvd, ParaView would draw it opaque over the
// particles. view.py (ParaView) shows the particles with it translucent.
void RunFiles::write_domain_surface() {
  const Domain& domain = run_.domain();
  bool surface = false;
  if (run_.config().domain.type != DomainType::Free) {
    const int cells = run_.config().run.dim == 3 ? 12 : 256;  // the sphere with its buffer: ~7k triangles, 0.14 MB
    SurfaceMesh mesh = boundary_surface(domain, 0.0, cells);
    std::vector<int> dirichlet;
    for (const PatchInfo& p : run_.patches())
      if (p.kind == PatchKind::Dirichlet) dirichlet.push_back(p.id);
    const double buffer = sim_.buffer().buffer_width;
    if (!dirichlet.empty() && buffer > 0.0) {
      const SurfaceMesh outer = boundary_surface(domain, buffer, cells, dirichlet);
      const auto base = static_cast<std::int64_t>(mesh.points.size());
      mesh.points.insert(mesh.points.end(), outer.points.begin(), outer.points.end());
      for (std::int64_t i : outer.cells) mesh.cells.push_back(base + i);
      for (int patch : outer.patch) mesh.patch.push_back(patch + domain.num_patches());
    }
    surface = mesh.num_cells() > 0;
    if (surface) write_file_atomic(out_ / "domain.vtp", surface_vtp(mesh));
  }
  write_file_atomic(out_ / "view.py", paraview_script("particles.pvd", surface ? "domain.vtp" : "",
                                                      std::filesystem::absolute(out_).string()));
}

}  // namespace otfp::app::detail
