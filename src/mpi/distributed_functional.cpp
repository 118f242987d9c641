// The functional (28) over the ranks of the MPI world (otfp/distributed_functional.hpp).
//
// Each rank evaluates the terms of the particles it owns with the serial
// kernels, on its own particles followed by its ghosts:
//   T, B: per particle, owned only;
//   E:    EntropyTerm with rows = owned (docs/method_notes.md#exact-gradient):
//         rho_p of an owned p sums its owned and ghost neighbours, and the
//         gradient holds, for every blob q (owned or ghost), the derivative
//         of the owned terms m_p log rho_p with respect to x_q.
// The derivative of a rank's terms with respect to one of its ghosts belongs
// to the ghost's owner: it is sent back and summed there (PetscSFReduce,
// MPI_SUM). Together the ranks so hold every term of (28) once and every
// derivative of it, with no second exchange of per-particle factors.
//
// Ghosts: every particle within the list radius R = r_c(s_max) + skin of the
// bounding box of another rank's particles goes to that rank (the boxes are
// all-gathered; periodic axes by minimum image). A pair enters the serial
// list when |x_p - x_q| <= max(R_p, R_q) <= R, so each owned particle finds
// all its list neighbours among its rank's blobs, with the same pair set as
// the serial list built at the same positions. The ghosts and the list are
// rebuilt together by the serial rule, taken over all ranks: when 2 x the
// largest displacement since the build plus the growth of a cut-off exceeds
// the skin.
//
// Image blobs (no-flux walls, the reservoir band's back face): each rank
// mirrors its own particles and its ghosts, by the serial rule (a blob within
// its list radius of a wall), and appends the images to its local blobs. An
// image enters an owned particle's list only if its source is among the
// rank's blobs: reflection across a plane, or across a sphere or cylinder
// the domain lies inside, never brings a point nearer the domain's side,
// |p - q| <= |p - R(q)| (MirrorWall::keeps_images_farther), so the source is
// within the list radius too; an obstacle's reflection can, and its ghosts
// are taken within three list radii. An image's derivative goes to
// its source by the reflection's chain rule (WallImages::pull_back), before
// the ghosts' share is sent back to the owners.
#include "otfp/distributed_functional.hpp"

#include <petscsf.h>
#include <petscsys.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>
#include <stdexcept>
#include <string>

#include "otfp/types.hpp"
#include "particle_exchange.hpp"
#include "petsc_session.hpp"

namespace otfp {


namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

using detail::distance_to_box;

}  // namespace

struct DistributedFunctional::Impl {
  int dim;
  FunctionalOptions options;
  TransportTerm transport;
  EntropyTerm entropy;
  BarrierTerm barrier;
  Periodicity per;
  NeighborList list;
  WallImages images;
  std::vector<Vec3> image_x, image_x_build, image_grad;  // images' positions (now, at the build), derivative

  MPI_Comm comm = MPI_COMM_NULL;
  int rank = 0, size = 1;
  MPI_Datatype vec3_type = MPI_DATATYPE_NULL;
  PetscSF sf = nullptr;

  std::vector<Vec3> x_ref;
  std::vector<double> s_ref, m, weights;  // weights: the transport's (BDF2), empty for 1
  std::size_t n_owned = 0;
  bool stale = true;  // set_reference() or no build yet

  // Local blobs: owned, then ghosts (filled by the star forest).
  std::vector<Vec3> x_local;
  std::vector<double> s_local, m_local, s_list_local;
  std::vector<Vec3> x_build;     // owned positions at the last build
  std::vector<double> s_build;   // owned list widths at the last build
  double skin = 0.0;
  Gradient scratch, barrier_scratch;
  std::size_t n_ghosts = 0;  // ghosts (x_local[n_owned, n_owned + n_ghosts)), then images
  std::size_t n_sent = 0;  // blobs this rank sends in each exchange (its copies as other ranks' ghosts)
  ExchangeStats stats;

  Impl(int d, FunctionalOptions o, Barrier b, Periodicity p)
      : dim(d),
        options(o),
        transport(o.dt, width_metric_coefficient(o.width_metric, d)),
        entropy(d, o.kappa, o.rho_ref),
        barrier(std::move(b)),
        per(p),
        list(o.neighbor) {}

  ~Impl() {
    // A functional that outlives PETSc (a static one, destroyed after the
    // atexit hook finalised PETSc and MPI) has nothing left to free.
    const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
    PetscBool finalized = PETSC_TRUE;
    if (PetscFinalized(&finalized) != 0 || finalized) return;
    if (sf != nullptr) PetscSFDestroy(&sf);
    if (vec3_type != MPI_DATATYPE_NULL) MPI_Type_free(&vec3_type);
  }

  double list_width(double s) const {
    return options.optimise_widths && options.width_skin > 0.0 ? (1.0 + options.width_skin) * s : s;
  }

  double allreduce(double v, MPI_Op op) const {
    double out = v;
    MPI_Allreduce(&v, &out, 1, MPI_DOUBLE, op, comm);
    return out;
  }

  // With images the ghosts' positions are sent first (the current star
  // forest), so that the images' displacement enters the rule too (the serial
  // list's covers particles and images alike).
  bool needs_rebuild(const std::vector<Vec3>& x, const std::vector<double>& s) {
    // A forced rebuild anywhere is every rank's (decided before the images'
    // exchange below, which every rank must join).
    int local = stale || x.size() != x_build.size() ? 1 : 0;
    int any = 0;
    MPI_Allreduce(&local, &any, 1, MPI_INT, MPI_MAX, comm);
    if (any != 0) return true;
    double measure = 0.0;
    {
      double disp2 = 0.0, growth = 0.0;
      for (std::size_t p = 0; p < x.size(); ++p) {
        disp2 = std::max(disp2, per.displacement(x[p], x_build[p]).squaredNorm());
        growth = std::max(growth, s[p] - s_build[p]);
      }
      if (images.active()) {
        bcast(x, s);
        images.positions(x_local, image_x);
        for (std::size_t i = 0; i < image_x.size(); ++i)
          disp2 = std::max(disp2, (image_x[i] - image_x_build[i]).squaredNorm());
      }
      measure = 2.0 * std::sqrt(disp2) + cutoff_radius(growth, options.neighbor.kernel_tolerance);
    }
    return allreduce(measure, MPI_MAX) > skin;
  }

  // New ghost sets, star forest and neighbour list for the owned (x, s).
  void rebuild(const std::vector<Vec3>& x, const std::vector<double>& s) {
    // The skin and the list radius are global, as the serial list's would be.
    double s_min = std::numeric_limits<double>::infinity(), s_max = 0.0;
    for (double v : s) {
      s_min = std::min(s_min, list_width(v));
      s_max = std::max(s_max, list_width(v));
    }
    s_min = allreduce(s_min, MPI_MIN);
    s_max = allreduce(s_max, MPI_MAX);
    if (!std::isfinite(s_min)) s_min = s_max = 1.0;  // no particle anywhere
    const NeighborOptions& no = options.neighbor;
    skin = no.skin >= 0.0 ? no.skin : no.skin_factor * s_min;
    const double radius = cutoff_radius(s_max, no.kernel_tolerance) + skin;
    // Ghosts: within the list radius R; with an obstacle's images, 3 R: an
    // image y_q within R of p has its source within R + |q - y_q| <= 3 R
    // (a blob is mirrored within its reach <= R of the wall).
    bool farther = true;
    for (const MirrorWallPtr& w : images.walls()) farther = farther && w->keeps_images_farther();
    const double ghost_radius = farther ? radius : 3.0 * radius;

    // Every rank's bounding box, [lo, hi], empty (lo > hi) for no particle.
    const std::vector<double> boxes = detail::all_boxes(x, comm);

    // What this rank sends: its particles within reach of each other box.
    std::vector<std::vector<PetscInt>> send(static_cast<std::size_t>(size));
    for (int r = 0; r < size; ++r) {
      if (r == rank) continue;
      const double* b = &boxes[6 * static_cast<std::size_t>(r)];
      if (b[0] > b[3]) continue;  // rank r owns nothing
      const Vec3 lo(b[0], b[1], b[2]), hi(b[3], b[4], b[5]);
      for (std::size_t p = 0; p < x.size(); ++p)
        if (distance_to_box(x[p], lo, hi, per, dim) <= ghost_radius)
          send[static_cast<std::size_t>(r)].push_back(static_cast<PetscInt>(p));
    }
    // Each receiver learns which (rank, index) fills each of its ghost slots.
    std::vector<int> send_counts(static_cast<std::size_t>(size)), recv_counts(static_cast<std::size_t>(size));
    for (int r = 0; r < size; ++r) send_counts[static_cast<std::size_t>(r)] = static_cast<int>(send[static_cast<std::size_t>(r)].size());
    MPI_Alltoall(send_counts.data(), 1, MPI_INT, recv_counts.data(), 1, MPI_INT, comm);
    std::vector<int> send_displ(static_cast<std::size_t>(size), 0), recv_displ(static_cast<std::size_t>(size), 0);
    for (int r = 1; r < size; ++r) {
      send_displ[static_cast<std::size_t>(r)] = send_displ[static_cast<std::size_t>(r - 1)] + send_counts[static_cast<std::size_t>(r - 1)];
      recv_displ[static_cast<std::size_t>(r)] = recv_displ[static_cast<std::size_t>(r - 1)] + recv_counts[static_cast<std::size_t>(r - 1)];
    }
    const int n_send = send_displ.back() + send_counts.back();
    n_sent = static_cast<std::size_t>(n_send);
    const int n_ghost = recv_displ.back() + recv_counts.back();
    std::vector<PetscInt> send_flat;
    send_flat.reserve(static_cast<std::size_t>(n_send));
    for (const auto& v : send) send_flat.insert(send_flat.end(), v.begin(), v.end());
    std::vector<PetscInt> roots(static_cast<std::size_t>(n_ghost));
    MPI_Alltoallv(send_flat.data(), send_counts.data(), send_displ.data(), MPIU_INT, roots.data(),
                  recv_counts.data(), recv_displ.data(), MPIU_INT, comm);
    std::vector<PetscSFNode> remote(static_cast<std::size_t>(n_ghost));
    for (int r = 0; r < size; ++r)
      for (int k = 0; k < recv_counts[static_cast<std::size_t>(r)]; ++k) {
        const auto slot = static_cast<std::size_t>(recv_displ[static_cast<std::size_t>(r)] + k);
        remote[slot].rank = r;
        remote[slot].index = roots[slot];
      }
    if (sf != nullptr) PetscSFDestroy(&sf);
    detail::petsc_check(PetscSFCreate(comm, &sf), "PetscSFCreate");
    detail::petsc_check(PetscSFSetGraph(sf, static_cast<PetscInt>(x.size()), n_ghost, nullptr, PETSC_COPY_VALUES,
                                        remote.data(), PETSC_COPY_VALUES),
                        "PetscSFSetGraph");
    detail::petsc_check(PetscSFSetUp(sf), "PetscSFSetUp");

    // Ghost data: positions, widths and masses.
    n_owned = x.size();
    n_ghosts = static_cast<std::size_t>(n_ghost);
    const std::size_t n_local = n_owned + n_ghosts;
    x_local.resize(n_local);
    s_local.resize(n_local);
    m_local.resize(n_local);
    std::copy(m.begin(), m.end(), m_local.begin());
    bcast(x, s);
    detail::petsc_check(PetscSFBcastBegin(sf, MPI_DOUBLE, m.data(), m_local.data() + n_owned, MPI_REPLACE), "bcast");
    detail::petsc_check(PetscSFBcastEnd(sf, MPI_DOUBLE, m.data(), m_local.data() + n_owned, MPI_REPLACE), "bcast");
    stats.bytes_sent += static_cast<double>(n_send) * sizeof(double);

    NeighborOptions local_options = no;
    local_options.skin = skin;
    list = NeighborList(local_options);
    if (images.active()) {
      // The serial rule (Functional::select_images): mirrored within r_c(s) + skin.
      const double rc_per_s = cutoff_radius(1.0, no.kernel_tolerance);
      std::vector<double> reach(n_local);
      for (std::size_t p = 0; p < n_local; ++p) reach[p] = list_width(s_local[p]) * rc_per_s + skin;
      images.select(x_local, reach);
      images.positions(x_local, image_x);
      image_x_build = image_x;
    }
    extend();
    s_list_local.resize(x_local.size());
    for (std::size_t p = 0; p < x_local.size(); ++p) s_list_local[p] = list_width(s_local[p]);
    list.build(x_local, s_list_local, per);
    stats.list_seconds += list.build_seconds();  // a new list: its one build
    // Ghost rows only gather the derivatives of the own terms: their
    // entries to other ghosts would add zeros (docs/distributed.md).
    list.drop_pairs_beyond(n_owned);
    x_build = x;
    s_build.resize(n_owned);
    for (std::size_t p = 0; p < n_owned; ++p) s_build[p] = list_width(s[p]);
    stale = false;
    ++stats.rebuilds;
    stats.ghosts = n_ghosts;
  }

  // The ghosts (and images) of the owned (x, s): rebuilt or refreshed
  // (collective). Returns the seconds it took.
  double sync(const std::vector<Vec3>& x, const std::vector<double>& s) {
    const auto t0 = Clock::now();
    if (needs_rebuild(x, s)) {
      rebuild(x, s);
    } else {
      if (!images.active()) bcast(x, s);  // with images needs_rebuild() has sent them
      extend();
    }
    return seconds_since(t0);
  }

  // Owned (x, s) into the local arrays, the ghosts' from their owners.
  // The images after the owned blobs and the ghosts: positions from their
  // sources' (x_local's first n_owned + n_ghost entries), widths and masses theirs.
  void extend() {
    const std::size_t n_src = n_owned + n_ghosts;
    const auto& src = images.sources();
    if (images.active()) images.positions(x_local, image_x);
    x_local.resize(n_src + src.size());
    s_local.resize(n_src + src.size());
    m_local.resize(n_src + src.size());
    for (std::size_t i = 0; i < src.size(); ++i) {
      x_local[n_src + i] = image_x[i];
      s_local[n_src + i] = s_local[src[i]];
      m_local[n_src + i] = m_local[src[i]];
    }
  }

  void bcast(const std::vector<Vec3>& x, const std::vector<double>& s) {
    std::copy(x.begin(), x.end(), x_local.begin());
    std::copy(s.begin(), s.end(), s_local.begin());
    Vec3* xg = x_local.data() + n_owned;
    detail::petsc_check(PetscSFBcastBegin(sf, vec3_type, x.data(), xg, MPI_REPLACE), "PetscSFBcastBegin");
    detail::petsc_check(PetscSFBcastEnd(sf, vec3_type, x.data(), xg, MPI_REPLACE), "PetscSFBcastEnd");
    detail::petsc_check(PetscSFBcastBegin(sf, MPI_DOUBLE, s.data(), s_local.data() + n_owned, MPI_REPLACE),
                        "PetscSFBcastBegin");
    detail::petsc_check(PetscSFBcastEnd(sf, MPI_DOUBLE, s.data(), s_local.data() + n_owned, MPI_REPLACE),
                        "PetscSFBcastEnd");
    stats.bytes_sent += static_cast<double>(n_sent) * (sizeof(Vec3) + sizeof(double));
  }
};

DistributedFunctional::DistributedFunctional(int dim, FunctionalOptions options, Barrier barrier,
                                             Periodicity periodicity) {
  options.validate();
  require(dim >= 1 && dim <= 3, "dim", dim, "must be 1, 2 or 3");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  detail::ensure_petsc();
  impl_ = std::make_unique<Impl>(dim, options, std::move(barrier), periodicity);
  impl_->comm = PETSC_COMM_WORLD;
  MPI_Comm_rank(impl_->comm, &impl_->rank);
  MPI_Comm_size(impl_->comm, &impl_->size);
  MPI_Type_contiguous(3, MPI_DOUBLE, &impl_->vec3_type);
  MPI_Type_commit(&impl_->vec3_type);
}

DistributedFunctional::~DistributedFunctional() = default;

void DistributedFunctional::set_reference(const std::vector<Vec3>& x_ref, const std::vector<double>& s_ref,
                                          const std::vector<double>& m, std::vector<double> transport_weights) {
  require(s_ref.size() == x_ref.size() && m.size() == x_ref.size(), "reference sizes",
          static_cast<double>(s_ref.size()), "x_ref, s_ref and m must have one entry per owned particle");
  require(transport_weights.empty() || transport_weights.size() == m.size(), "transport_weights size",
          static_cast<double>(transport_weights.size()), "must be 0 or the number of owned particles");
  for (double a : transport_weights)
    require(std::isfinite(a) && a > 0.0, "transport weight", a, "must be finite and > 0");
  impl_->weights = std::move(transport_weights);
  impl_->x_ref = x_ref;
  impl_->s_ref = s_ref;
  impl_->m = m;
  impl_->stale = true;
}

FunctionalParts DistributedFunctional::evaluate(const std::vector<Vec3>& x, const std::vector<double>& s,
                                                Gradient* grad) {
  Impl& d = *impl_;
  require(x.size() == d.m.size() && s.size() == d.m.size(), "configuration size", static_cast<double>(x.size()),
          "must match the owned particles set by set_reference()");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  double exchange = d.sync(x, s);

  const std::size_t n = d.n_owned, n_local = d.n_owned + d.n_ghosts, n_ext = d.x_local.size();
  const bool widths = grad && d.options.optimise_widths;
  FunctionalParts parts;
  if (grad) {
    grad->resize(n, widths);
    d.scratch.resize(n_ext, widths);
  }
  parts.transport = d.transport.evaluate(x, s, d.m, d.x_ref, d.s_ref, grad, d.weights);
  parts.entropy = d.entropy.evaluate(d.x_local, d.s_local, d.m_local, d.list, grad ? &d.scratch : nullptr, n);
  if (grad) {
    if (d.images.active()) {
      // Images move with their sources (owned or ghost: the chain rule
      // through the reflection) and share their widths.
      const auto& src = d.images.sources();
      d.image_grad.assign(d.scratch.x.begin() + static_cast<std::ptrdiff_t>(n_local), d.scratch.x.end());
      d.images.pull_back(d.x_local, d.image_grad, d.scratch.x);
      if (widths)
        for (std::size_t i = 0; i < src.size(); ++i) d.scratch.s[src[i]] += d.scratch.s[n_local + i];
    }
    for (std::size_t p = 0; p < n; ++p) grad->x[p] += d.scratch.x[p];
    if (widths)
      for (std::size_t p = 0; p < n; ++p) grad->s[p] += d.scratch.s[p];
    // The ghosts' share goes back to their owners, summed there.
    const auto t1 = Clock::now();
    detail::petsc_check(PetscSFReduceBegin(d.sf, d.vec3_type, d.scratch.x.data() + n, grad->x.data(), MPI_SUM),
                        "PetscSFReduceBegin");
    detail::petsc_check(PetscSFReduceEnd(d.sf, d.vec3_type, d.scratch.x.data() + n, grad->x.data(), MPI_SUM),
                        "PetscSFReduceEnd");
    if (widths) {
      detail::petsc_check(PetscSFReduceBegin(d.sf, MPI_DOUBLE, d.scratch.s.data() + n, grad->s.data(), MPI_SUM),
                          "PetscSFReduceBegin");
      detail::petsc_check(PetscSFReduceEnd(d.sf, MPI_DOUBLE, d.scratch.s.data() + n, grad->s.data(), MPI_SUM),
                          "PetscSFReduceEnd");
    }
    d.stats.bytes_sent += static_cast<double>(n_local - n) * (sizeof(Vec3) + (widths ? sizeof(double) : 0));
    exchange += seconds_since(t1);
    d.barrier_scratch.resize(n, false);
    parts.barrier = d.barrier.evaluate(x, d.m, &d.barrier_scratch);
    for (std::size_t p = 0; p < n; ++p) grad->x[p] += d.barrier_scratch.x[p];
  } else {
    parts.barrier = d.barrier.evaluate(x, d.m, nullptr);
  }
  const auto t2 = Clock::now();
  double local[3] = {parts.transport, parts.entropy, parts.barrier}, global[3];
  MPI_Allreduce(local, global, 3, MPI_DOUBLE, MPI_SUM, d.comm);
  exchange += seconds_since(t2);
  parts.transport = global[0];
  parts.entropy = global[1];
  parts.barrier = global[2];
  d.stats.seconds += exchange;
  ++d.stats.evaluations;
  return parts;
}

void DistributedFunctional::explicit_velocity(const std::vector<Vec3>& x, const std::vector<double>& s,
                                              std::vector<Vec3>& v) {
  Impl& d = *impl_;
  require(x.size() == d.m.size() && s.size() == d.m.size(), "configuration size", static_cast<double>(x.size()),
          "must match the owned particles set by set_reference()");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  const double exchange = d.sync(x, s);
  // rho and grad rho at the owned particles from every blob within reach:
  // own, ghosts and images (the serial Functional::explicit_velocity).
  const std::size_t n = d.n_owned;
  d.entropy.evaluate(d.x_local, d.s_local, d.m_local, d.list, nullptr, n);
  const auto& rho = d.entropy.density();
  const auto& grho = d.entropy.density_gradient();
  v.resize(n);
  const double kappa = d.options.kappa;
#pragma omp parallel for schedule(static)
  for (std::size_t r = 0; r < n; ++r) {
    Vec3 gpsi;
    d.barrier.barrier().value(x[r], &gpsi);
    v[r] = -(kappa * grho[r] / rho[r] + gpsi);  // force (27), term 1, and the barrier's
  }
  d.stats.seconds += exchange;
  ++d.stats.evaluations;
}

void DistributedFunctional::set_images(WallImages images) {
  require(!images.active() || !impl_->per.any(), "images", "walls", "cannot be combined with a periodic box");
  impl_->images = std::move(images);
  impl_->stale = true;
}

const WallImages& DistributedFunctional::images() const { return impl_->images; }

void DistributedFunctional::set_dt(double dt) {
  require(std::isfinite(dt) && dt > 0.0, "dt", dt, "must be finite and > 0");
  impl_->options.dt = dt;
  impl_->transport = TransportTerm(dt, width_metric_coefficient(impl_->options.width_metric, impl_->dim));
}

std::size_t DistributedFunctional::owned() const { return impl_->m.size(); }
const ExchangeStats& DistributedFunctional::exchange() const { return impl_->stats; }
std::uint64_t DistributedFunctional::pair_evaluations() const { return impl_->entropy.pair_evaluations(); }

void DistributedFunctional::add_step_work(double list_seconds_before, std::uint64_t pairs_before,
                                          StepSummary& summary) const {
  double seconds = impl_->stats.list_seconds - list_seconds_before;
  auto pairs = static_cast<unsigned long long>(impl_->entropy.pair_evaluations() - pairs_before);
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  MPI_Allreduce(MPI_IN_PLACE, &seconds, 1, MPI_DOUBLE, MPI_MAX, impl_->comm);
  MPI_Allreduce(MPI_IN_PLACE, &pairs, 1, MPI_UNSIGNED_LONG_LONG, MPI_SUM, impl_->comm);
  summary.list_seconds += seconds;
  summary.pair_evaluations += static_cast<std::uint64_t>(pairs);
}
const NeighborList& DistributedFunctional::list() const { return impl_->list; }

std::size_t DistributedFunctional::ghosts() const { return impl_->n_ghosts; }

std::vector<double> DistributedFunctional::ghost_values(const std::vector<double>& own, int k) {
  Impl& d = *impl_;
  require(k >= 1, "k", k, "must be >= 1");
  require(own.size() == d.n_owned * static_cast<std::size_t>(k), "own values", static_cast<double>(own.size()),
          "must be k per owned particle of the last build");
  require(d.sf != nullptr, "ghost_values", 0.0, "needs a build (an evaluation) first");
  const std::lock_guard<std::recursive_mutex> lock(detail::petsc_mutex());
  std::vector<double> out(d.n_ghosts * static_cast<std::size_t>(k));
  MPI_Datatype row = MPI_DATATYPE_NULL;
  MPI_Type_contiguous(k, MPI_DOUBLE, &row);
  MPI_Type_commit(&row);
  detail::petsc_check(PetscSFBcastBegin(d.sf, row, own.data(), out.data(), MPI_REPLACE), "PetscSFBcastBegin");
  detail::petsc_check(PetscSFBcastEnd(d.sf, row, own.data(), out.data(), MPI_REPLACE), "PetscSFBcastEnd");
  MPI_Type_free(&row);
  return out;
}

}  // namespace otfp
