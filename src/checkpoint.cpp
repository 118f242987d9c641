// Simulation::save_checkpoint and load_checkpoint (the rest of Simulation is
// in simulation.cpp).
#include "otfp/simulation.hpp"
#include "otfp/run_distribution.hpp"

#include "file_read.hpp"

#include <fcntl.h>
#include <sys/stat.h>

#include <charconv>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <type_traits>
#include <unistd.h>

#include "otfp/implicit_stepper.hpp"

namespace otfp {

// ------------------------------------------------------------------ checkpoints
//
// Binary, native byte order (a checkpoint is for the machine that wrote it):
// "OTFPCKP2", then the fields below in order, then an FNV-1a 64 checksum of
// everything before it. Format 2 added the setup fingerprint and put the
// caller's data before the state (checkpoint_extra() reads it alone).

namespace {

constexpr char kMagic[8] = {'O', 'T', 'F', 'P', 'C', 'K', 'P', '2'};
constexpr char kMagicV1[8] = {'O', 'T', 'F', 'P', 'C', 'K', 'P', '1'};

class Writer {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const char* p = reinterpret_cast<const char*>(&v);
    bytes_.append(p, sizeof(T));
  }
  void put_vec(const Vec3& v) {
    for (int k = 0; k < 3; ++k) put(v[k]);
  }
  void put_string(const std::string& s) {
    put(static_cast<std::uint64_t>(s.size()));
    bytes_ += s;
  }
  std::string& bytes() { return bytes_; }

 private:
  std::string bytes_;
};

class Reader {
 public:
  Reader(const std::string& bytes, std::string file) : bytes_(bytes), file_(std::move(file)) {}
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    if (pos_ + sizeof(T) > bytes_.size()) fail("truncated");
    T v;
    std::memcpy(&v, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  Vec3 get_vec() {
    Vec3 v;
    for (int k = 0; k < 3; ++k) v[k] = get<double>();
    return v;
  }
  std::string get_string() {
    const auto n = get<std::uint64_t>();
    if (n > bytes_.size() - pos_) fail("truncated");
    std::string s = bytes_.substr(pos_, n);
    pos_ += n;
    return s;
  }
  // A count of records of `record_bytes` each that must follow: at most what
  // the bytes left can hold (a damaged count cannot allocate more than the
  // file's size).
  std::uint64_t count(std::size_t record_bytes, const char* what) {
    const auto n = get<std::uint64_t>();
    if (n > (bytes_.size() - pos_) / record_bytes)
      fail(std::string(what) + " count " + std::to_string(n) + " exceeds what the file's remaining " +
           std::to_string(bytes_.size() - pos_) + " bytes can hold (truncated or damaged)");
    return n;
  }
  [[noreturn]] void fail(const std::string& why) const {
    throw InvalidArgument("checkpoint " + file_ + ": " + why);
  }
  bool at_end() const { return pos_ == bytes_.size(); }

 private:
  const std::string& bytes_;
  std::string file_;
  std::size_t pos_ = 0;
};

std::uint64_t fnv1a(const char* p, std::size_t n) {
  std::uint64_t h = 14695981039346656037ull;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(p[i]);
    h *= 1099511628211ull;
  }
  return h;
}

void put_patch_ledger(Writer& w, const PatchLedger& l) {
  w.put(static_cast<std::int64_t>(l.inserted));
  w.put(static_cast<std::int64_t>(l.removed));
  w.put(l.mass_inserted);
  w.put(l.mass_removed);
  w.put(static_cast<std::int64_t>(l.absorbed));
  w.put(l.mass_absorbed);
  w.put(l.flux_integral);
  w.put(l.carry);
  w.put(l.deficit);
}

PatchLedger get_patch_ledger(Reader& r) {
  PatchLedger l;
  l.inserted = static_cast<long>(r.get<std::int64_t>());
  l.removed = static_cast<long>(r.get<std::int64_t>());
  l.mass_inserted = r.get<double>();
  l.mass_removed = r.get<double>();
  l.absorbed = static_cast<long>(r.get<std::int64_t>());
  l.mass_absorbed = r.get<double>();
  l.flux_integral = r.get<double>();
  l.carry = r.get<double>();
  l.deficit = r.get<double>();
  return l;
}

std::string shortest(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, r.ptr);
}

// What a checkpoint may only be loaded into: the domain, the boundary data and
// the options that give the state its meaning (widths, masses, the physics,
// the treatment of the boundaries, the stepper), one "name = value" line
// each. Options a caller may change between the save and the load (the
// resource limit, the adaptive controller, solver tolerances, the seed, which
// only start() uses) are not part of it.
std::string setup_fingerprint(const Domain& domain, const std::vector<ConstantBoundaryData>& boundary,
                              const SimulationOptions& o) {
  std::string out;
  auto line = [&out](const std::string& name, const std::string& value) { out += name + " = " + value + "\n"; };
  // Appended piece by piece: GCC 12's -Wrestrict misfires on a chain of + here.
  auto vec = [](const Vec3& v) {
    std::string t = "[";
    for (int k = 0; k < 3; ++k) {
      t += shortest(v[k]);
      t += k < 2 ? ", " : "]";
    }
    return t;
  };
  line("domain.dim", std::to_string(domain.dim()));
  line("domain.patches", std::to_string(domain.num_patches()));
  line("domain.periodic", domain.is_periodic() ? "true" : "false");
  if (domain.is_periodic()) line("domain.period", vec(domain.period()));
  line("domain.volume", shortest(domain.volume()));
  const Aabb box = domain.bounding_box();
  line("domain.bounding_box", vec(box.lo) + " - " + vec(box.hi));
  for (int p = 0; p < domain.num_patches(); ++p)
    line("domain.patch[" + std::to_string(p) + "]", domain.patch_name(p) + ", area " + shortest(domain.patch_area(p)));
  for (std::size_t i = 0; i < boundary.size(); ++i) {
    const ConstantBoundaryData& b = boundary[i];
    line("boundary[" + std::to_string(i) + "]", "patch " + std::to_string(b.patch) + ", " + to_string(b.kind) + " " +
                                                    shortest(b.value) + " over [" + shortest(b.t_start) + ", " +
                                                    shortest(b.t_end) + ")");
  }
  line("particle_mass", shortest(o.particle_mass));
  line("width_s", shortest(o.width_s));
  line("bounded", o.bounded ? "true" : "false");
  line("barrier_stiffness", shortest(o.barrier_stiffness));
  line("no_flux", to_string(o.no_flux));
  const ProjectionOptions& po = o.projection;
  line("projection.layer_b", shortest(po.layer_b));
  line("projection.dirichlet_target", to_string(po.dirichlet_target));
  line("projection.neumann_outflow", to_string(po.neumann_outflow));
  line("projection.dirichlet_mode", to_string(po.dirichlet_mode));
  line("projection.reservoir_thickness", shortest(po.reservoir_thickness));
  line("projection.reservoir_sublayers", std::to_string(po.reservoir_sublayers));
  line("projection.reservoir_profile", to_string(po.reservoir_profile));
  line("projection.absorb_exterior", po.absorb_exterior ? "true" : "false");
  line("stepper", to_string(o.stepper));
  if (o.stepper == StepperKind::Implicit) {
    line("implicit.kappa", shortest(o.implicit.kappa));
    line("implicit.rho_ref", shortest(o.implicit.rho_ref));
    line("implicit.time_scheme", to_string(o.implicit.time_scheme));
    line("implicit.width_mode", to_string(o.implicit.width_mode));
  } else {
    line("explicit_options.scheme", to_string(o.explicit_options.scheme));
    line("explicit_options.kappa", shortest(o.explicit_options.kappa));
    line("explicit_options.rho_ref", shortest(o.explicit_options.rho_ref));
  }
  line("velocity", vec(o.velocity));
  line("source_rate", shortest(o.source_rate));
  return out;
}

// The first line of `mine` that `theirs` does not hold, as "name = <theirs> in
// the file, <mine> here" (empty when they agree).
std::string first_difference(const std::string& theirs, const std::string& mine) {
  auto lines = [](const std::string& text) {
    std::vector<std::pair<std::string, std::string>> out;
    std::istringstream in(text);
    for (std::string l; std::getline(in, l);) {
      const std::size_t eq = l.find(" = ");
      out.emplace_back(l.substr(0, eq), eq == std::string::npos ? "" : l.substr(eq + 3));
    }
    return out;
  };
  const auto a = lines(theirs), b = lines(mine);
  for (const auto& [name, value] : b) {
    std::string other = "(absent)";
    for (const auto& [n, v] : a)
      if (n == name) other = v;
    if (other != value) return name + " = " + other + " in the file, " + value + " here";
  }
  for (const auto& [name, value] : a) {
    bool found = false;
    for (const auto& [n, v] : b) found = found || n == name;
    if (!found) return name + " = " + value + " in the file, absent here";
  }
  return theirs == mine ? "" : "the setup";
}

// The bytes of a checkpoint file before its checksum, checked: a regular file
// (a FIFO or a device such as /dev/zero would block or never end), at most
// half the machine's memory, the magic of this format and the checksum.
std::string read_verified(const std::filesystem::path& path) {
  const std::string name = "checkpoint " + path.string() + ": ";
  std::string bytes;
  try {
    bytes = detail::read_regular_file(path);
  } catch (const detail::FileReadError& e) {
    throw InvalidArgument(name + e.what());
  }
  if (bytes.size() >= sizeof(kMagicV1) && std::memcmp(bytes.data(), kMagicV1, sizeof(kMagicV1)) == 0)
    throw InvalidArgument(name + "written by an older otfp (format 1, without a setup fingerprint): not loadable");
  if (bytes.size() < sizeof(kMagic) + 8 || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0)
    throw InvalidArgument(name + "not an otfp checkpoint (bad magic)");
  std::uint64_t stored;
  std::memcpy(&stored, bytes.data() + bytes.size() - 8, 8);
  if (fnv1a(bytes.data(), bytes.size() - 8) != stored) throw InvalidArgument(name + "checksum mismatch (damaged file)");
  bytes.resize(bytes.size() - 8);
  return bytes;
}

}  // namespace

std::string Simulation::checkpoint_extra(const std::filesystem::path& path) {
  const std::string body = read_verified(path);
  Reader b(body, path.string());
  for (std::size_t i = 0; i < sizeof(kMagic); ++i) b.get<char>();
  b.get<std::int32_t>();
  b.get<std::int32_t>();
  b.get<std::uint64_t>();
  b.get<std::int32_t>();
  b.get_string();
  return b.get_string();
}

// Over several processes: the union of the shares (in id order) is written
// by the root process, and every process learns whether it succeeded; a
// checkpoint so does not depend on the number of processes that wrote it.
void Simulation::save_checkpoint(const std::filesystem::path& path, const std::string& extra) const {
  require_started("save_checkpoint");
  if (!distribution_) {
    write_checkpoint(path, extra, particles_, implicit_ ? implicit_->history_state() : HistoryState{});
    return;
  }
  const ParticleSet all = distribution_->gather(particles_);
  const HistoryState history = distribution_->gathered_history();
  std::exception_ptr failed;
  if (distribution_->root()) {
    try {
      write_checkpoint(path, extra, all, history);
    } catch (...) {
      failed = std::current_exception();
    }
  }
  if (distribution_->sum(std::int64_t{failed ? 1 : 0}) == 0) return;
  if (failed) std::rethrow_exception(failed);
  throw std::runtime_error("cannot write checkpoint " + path.string() + " (the writing process names the cause)");
}

void Simulation::write_checkpoint(const std::filesystem::path& path, const std::string& extra,
                                  const ParticleSet& particles, const HistoryState& hs) const {
  Writer w;
  w.bytes().append(kMagic, sizeof(kMagic));
  w.put(static_cast<std::int32_t>(domain_->dim()));
  w.put(static_cast<std::int32_t>(domain_->num_patches()));
  w.put(static_cast<std::uint64_t>(boundary_.size()));
  w.put(static_cast<std::int32_t>(options_.stepper == StepperKind::Implicit));
  w.put_string(setup_fingerprint(*domain_, boundary_, options_));
  w.put_string(extra);
  w.put(time_);
  w.put(step_);
  w.put(dt_next_);
  // Particles, in their current order (the order is part of the state).
  w.put(static_cast<std::uint64_t>(particles.size()));
  w.put(particles.next_id());
  for (std::size_t p = 0; p < particles.size(); ++p) {
    w.put(particles.ids()[p]);
    w.put_vec(particles.positions()[p]);
    w.put(particles.widths()[p]);
    w.put(particles.masses()[p]);
    w.put(particles.birth_times()[p]);
  }
  const Rng::State rs = rng_.state();
  for (std::uint64_t v : rs.s) w.put(v);
  w.put(static_cast<std::int32_t>(rs.has_spare));
  w.put(rs.spare);
  w.put(ledger_);
  w.put(totals_);
  const BoundaryProjection::State ps = projection_->state();
  w.put(static_cast<std::uint64_t>(ps.ledger.size()));
  for (const PatchLedger& l : ps.ledger) put_patch_ledger(w, l);
  w.put(static_cast<std::uint64_t>(ps.reservoir_carry.size()));
  for (const auto& c : ps.reservoir_carry) {
    w.put(static_cast<std::uint64_t>(c.size()));
    for (double v : c) w.put(v);
  }
  w.put(hs.dt1);
  w.put(hs.dt2);
  w.put(static_cast<std::uint64_t>(hs.entries.size()));
  for (const auto& e : hs.entries) {
    w.put(e.id);
    w.put_vec(e.d1);
    w.put_vec(e.d2);
    w.put(e.ds1);
    w.put(e.ds2);
    w.put(static_cast<std::int32_t>(e.count));
  }
  w.put(initial_.inserted);
  w.put(initial_.removed);
  // run()'s grid of fixed steps (last: files without it load with no grid).
  w.put(grid_.t_origin);
  w.put(grid_.k_origin);
  w.put(grid_.dt);
  w.put(grid_.k_end);
  w.put(grid_.t_end);
  w.put(fnv1a(w.bytes().data(), w.bytes().size()));

  // Atomic: a temporary file in the same directory, flushed, then renamed.
  const std::filesystem::path tmp = path.string() + ".tmp" + std::to_string(::getpid());
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw std::runtime_error("cannot write checkpoint " + tmp.string());
    f.write(w.bytes().data(), static_cast<std::streamsize>(w.bytes().size()));
    f.flush();
    if (!f) {
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      throw std::runtime_error("cannot write checkpoint " + tmp.string() + " (disk full?)");
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw std::runtime_error("cannot rename checkpoint to " + path.string());
  }
}

// Over several processes: every process reads the file; the root keeps the
// particles and they are redistributed, so a checkpoint loads on any number
// of processes. A file that fails to load on one fails on all, each with its
// state as it was.
void Simulation::load_checkpoint(const std::filesystem::path& path, std::string* extra) {
  if (!distribution_) {
    load_checkpoint_file(path, extra);
    return;
  }
  const bool was_started = started_;
  const TimeGrid grid = grid_;
  const SimulationStep initial = initial_;
  const HistoryState history = distribution_->local_history();
  save_state();
  std::exception_ptr failed;
  try {
    load_checkpoint_file(path, extra);
  } catch (...) {
    failed = std::current_exception();
  }
  if (distribution_->sum(std::int64_t{failed ? 1 : 0}) > 0) {
    if (!failed) {
      restore_state();
      distribution_->restore_history(history);
      started_ = was_started;
      grid_ = grid;
      initial_ = initial;
    }
    if (failed) std::rethrow_exception(failed);
    throw InvalidArgument("checkpoint " + path.string() + ": another process could not load it (its error names the cause)");
  }
  if (!distribution_->root()) {
    const ParticleId next = particles_.next_id();
    particles_ = ParticleSet(domain_->dim());
    particles_.set_next_id(next);
  }
  distribution_->redistribute(particles_);
}

void Simulation::load_checkpoint_file(const std::filesystem::path& path, std::string* extra) {
  const std::string body = read_verified(path);
  Reader b(body, path.string());
  for (std::size_t i = 0; i < sizeof(kMagic); ++i) b.get<char>();
  if (b.get<std::int32_t>() != domain_->dim()) b.fail("written for another dimension");
  if (b.get<std::int32_t>() != domain_->num_patches()) b.fail("written for a domain with other patches");
  if (b.get<std::uint64_t>() != boundary_.size()) b.fail("written with other boundary data");
  if ((b.get<std::int32_t>() != 0) != (options_.stepper == StepperKind::Implicit)) b.fail("written with another stepper");
  const std::string difference = first_difference(b.get_string(), setup_fingerprint(*domain_, boundary_, options_));
  if (!difference.empty()) b.fail("written by a Simulation of another setup: " + difference);
  std::string user = b.get_string();
  const double t = b.get<double>();
  const auto step = b.get<std::int64_t>();
  const double dt_next = b.get<double>();
  // A particle record: id, position, width, mass, birth time.
  constexpr std::size_t kParticleRecord = sizeof(ParticleId) + 3 * sizeof(double) + 3 * sizeof(double);
  const std::uint64_t n = b.count(kParticleRecord, "particle");
  const auto next_id = b.get<ParticleId>();
  ParticleSet particles(domain_->dim());
  particles.reserve(n);
  try {
    for (std::uint64_t i = 0; i < n; ++i) {
      const auto id = b.get<ParticleId>();
      const Vec3 x = b.get_vec();
      const double s = b.get<double>(), m = b.get<double>(), birth = b.get<double>();
      particles.add_with_id(id, x, s, m, birth);
    }
    particles.set_next_id(next_id);
  } catch (const InvalidArgument& e) {
    b.fail(e.what());
  }
  Rng::State rs;
  for (std::uint64_t& v : rs.s) v = b.get<std::uint64_t>();
  rs.has_spare = b.get<std::int32_t>() != 0;
  rs.spare = b.get<double>();
  const auto ledger = b.get<SimulationLedger>();
  const auto totals = b.get<SimulationTotals>();
  BoundaryProjection::State ps;
  ps.ledger.resize(b.count(6 * sizeof(double) + 3 * sizeof(std::int64_t), "condition"));
  for (PatchLedger& l : ps.ledger) l = get_patch_ledger(b);
  ps.reservoir_carry.resize(b.count(sizeof(std::uint64_t), "reservoir"));
  for (auto& c : ps.reservoir_carry) {
    c.resize(b.count(sizeof(double), "sublayer"));
    for (double& v : c) v = b.get<double>();
  }
  ImplicitStepper::HistoryState hs;
  hs.dt1 = b.get<double>();
  hs.dt2 = b.get<double>();
  // A history record: id, d1, d2, ds1, ds2, count.
  constexpr std::size_t kHistoryRecord = sizeof(ParticleId) + 8 * sizeof(double) + sizeof(std::int32_t);
  hs.entries.resize(b.count(kHistoryRecord, "history"));
  for (auto& e : hs.entries) {
    e.id = b.get<ParticleId>();
    e.d1 = b.get_vec();
    e.d2 = b.get_vec();
    e.ds1 = b.get<double>();
    e.ds2 = b.get<double>();
    e.count = b.get<std::int32_t>();
  }
  const auto ins0 = b.get<std::int64_t>(), rem0 = b.get<std::int64_t>();
  TimeGrid grid;
  if (!b.at_end()) {
    grid.t_origin = b.get<double>();
    grid.k_origin = b.get<std::int64_t>();
    grid.dt = b.get<double>();
    grid.k_end = b.get<std::int64_t>();
    grid.t_end = b.get<double>();
    if (!(std::isfinite(grid.t_origin) && std::isfinite(grid.dt) && grid.dt >= 0.0 && std::isfinite(grid.t_end) &&
          grid.k_origin >= 0 && grid.k_end >= grid.k_origin))
      b.fail("a damaged grid of steps");
  }
  if (!b.at_end()) b.fail("trailing bytes");
  if (!std::isfinite(t)) b.fail("non-finite time");

  // Everything read: apply (each restore validates before changing anything).
  try {
    Rng(0).set_state(rs);
    const BoundaryProjection::State old = projection_->state();
    projection_->restore(ps);
    // Over several processes the root keeps the particles until they are
    // redistributed, and their history with them; the others keep none.
    if (distribution_ && !distribution_->root()) hs.entries.clear();
    if (implicit_ || distribution_) {
      try {
        if (implicit_)
          implicit_->restore_history(hs);
        else
          distribution_->restore_history(hs);
      } catch (...) {
        projection_->restore(old);
        throw;
      }
    }
    rng_.set_state(rs);
  } catch (const InvalidArgument& e) {
    b.fail(e.what());
  }
  particles_ = std::move(particles);
  time_ = t;
  step_ = step;
  dt_next_ = dt_next;
  grid_ = grid;
  ledger_ = ledger;
  totals_ = totals;
  initial_ = SimulationStep{};
  initial_.inserted = ins0;
  initial_.removed = rem0;
  initial_.diffusion.accepted = true;
  started_ = true;
  if (extra) *extra = std::move(user);
}

}  // namespace otfp
