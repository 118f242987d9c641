#include "otfp/surface.hpp"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>

#include "vtk_xml.hpp"

namespace otfp {

namespace {

// Builds the mesh: crossing points are shared between the cells that meet
// at a grid edge, keyed by its two end nodes (a node itself where f = 0 there).
class Builder {
 public:
  Builder(const Domain& domain, const std::vector<int>& patches, std::uint64_t num_nodes)
      : domain_(domain), patches_(patches), num_nodes_(num_nodes) {
    mesh_.dim = domain.dim();
  }

  // Index of the crossing on the edge from node a (f <= 0) to node b (f > 0).
  std::int64_t crossing(std::uint64_t a, std::uint64_t b, const Vec3& xa, const Vec3& xb, double fa, double fb) {
    const bool at_node = fa == 0.0;
    const std::uint64_t key = at_node ? a * num_nodes_ + a : std::min(a, b) * num_nodes_ + std::max(a, b);
    const auto [it, fresh] = index_.emplace(key, static_cast<std::int64_t>(mesh_.points.size()));
    if (fresh) mesh_.points.push_back(at_node ? xa : Vec3(xa + (fa / (fa - fb)) * (xb - xa)));
    return it->second;
  }

  // Adds a cell unless it is degenerate or its patch is not wanted.
  // `outward` points from the inside to the outside of the cell's simplex.
  void cell(std::array<std::int64_t, 3> v, int n, const Vec3& outward) {
    const auto& P = mesh_.points;
    Vec3 centroid = Vec3::Zero();
    for (int i = 0; i < n; ++i) centroid += P[static_cast<std::size_t>(v[static_cast<std::size_t>(i)])];
    centroid /= n;
    if (n == 3) {
      const Vec3 normal = (P[v[1]] - P[v[0]]).cross(P[v[2]] - P[v[0]]);
      if (normal.squaredNorm() == 0.0) return;
      if (normal.dot(outward) < 0.0) std::swap(v[1], v[2]);
    } else if (n == 2) {
      const Vec3 d = P[v[1]] - P[v[0]];
      if (d.squaredNorm() == 0.0) return;
      if (Vec3(d[1], -d[0], 0.0).dot(outward) < 0.0) std::swap(v[0], v[1]);  // normal = d turned clockwise
    }
    const int patch = domain_.query(centroid).patch;
    if (!patches_.empty() && std::find(patches_.begin(), patches_.end(), patch) == patches_.end()) return;
    for (int i = 0; i < n; ++i) mesh_.cells.push_back(v[static_cast<std::size_t>(i)]);
    mesh_.patch.push_back(patch);
  }

  // Marching simplex: the part of the iso-surface f = 0 inside a simplex of
  // dim + 1 nodes. Inside (f <= 0) and outside nodes are separated by the
  // crossings on the edges between them: one cell, or two for 2 + 2 in a tetrahedron.
  void simplex(const std::uint64_t* g, const Vec3* x, const double* f, int nodes) {
    int in[4], out[4], ni = 0, no = 0;
    for (int i = 0; i < nodes; ++i) (f[i] <= 0.0 ? in[ni++] : out[no++]) = i;
    if (ni == 0 || no == 0) return;
    Vec3 ci = Vec3::Zero(), co = Vec3::Zero();
    for (int i = 0; i < ni; ++i) ci += x[in[i]];
    for (int i = 0; i < no; ++i) co += x[out[i]];
    const Vec3 outward = co / no - ci / ni;
    auto cross = [&](int a, int b) { return crossing(g[a], g[b], x[a], x[b], f[a], f[b]); };
    if (nodes == 2) {
      cell({cross(in[0], out[0]), 0, 0}, 1, outward);
    } else if (nodes == 3) {
      // One lone node (inside or outside): the segment across its two edges.
      if (ni == 1)
        cell({cross(in[0], out[0]), cross(in[0], out[1]), 0}, 2, outward);
      else
        cell({cross(in[0], out[0]), cross(in[1], out[0]), 0}, 2, outward);
    } else if (ni == 1) {
      cell({cross(in[0], out[0]), cross(in[0], out[1]), cross(in[0], out[2])}, 3, outward);
    } else if (no == 1) {
      cell({cross(in[0], out[0]), cross(in[1], out[0]), cross(in[2], out[0])}, 3, outward);
    } else {
      // Two in (a, b), two out (c, d): the quad ac, ad, bd, bc, cut along ac-bd.
      const std::int64_t ac = cross(in[0], out[0]), ad = cross(in[0], out[1]);
      const std::int64_t bd = cross(in[1], out[1]), bc = cross(in[1], out[0]);
      cell({ac, ad, bd}, 3, outward);
      cell({ac, bd, bc}, 3, outward);
    }
  }

  SurfaceMesh take() { return std::move(mesh_); }

 private:
  const Domain& domain_;
  const std::vector<int>& patches_;
  std::uint64_t num_nodes_;
  std::unordered_map<std::uint64_t, std::int64_t> index_;
  SurfaceMesh mesh_;
};

}  // namespace

SurfaceMesh boundary_surface(const Domain& domain, double offset, int cells_per_axis, const std::vector<int>& patches) {
  require(std::isfinite(offset), "boundary_surface: offset", offset, "must be finite");
  require(cells_per_axis >= 4 && cells_per_axis <= 4096, "boundary_surface: cells_per_axis", cells_per_axis,
          "must be in [4, 4096]");
  const int dim = domain.dim();
  SurfaceMesh empty;
  empty.dim = dim;
  if (domain.is_periodic() || domain.num_patches() == 0) return empty;

  // Grid: cells_per_axis cells per axis over the box grown by max(offset, 0)
  // plus one cell, so that the surface never touches the grid's border and,
  // at offset 0, the faces of a box fall on grid planes.
  const Aabb box = domain.bounding_box();
  const double grow = std::max(offset, 0.0);
  const int n = cells_per_axis;
  std::array<double, 3> lo{0.0, 0.0, 0.0}, h{0.0, 0.0, 0.0};
  std::array<std::uint64_t, 3> nodes{1, 1, 1};
  static const char* kAxis[3] = {"x", "y", "z"};
  for (int k = 0; k < dim; ++k) {
    const double extent = box.hi[k] - box.lo[k] + 2.0 * grow;
    require(std::isfinite(extent) && extent > 0.0, std::string("boundary_surface: bounding box extent along ") + kAxis[k],
            extent, "must be finite and > 0");
    h[k] = extent / (n - 2);
    lo[k] = box.lo[k] - grow - h[k];
    nodes[k] = static_cast<std::uint64_t>(n) + 1;
  }
  const std::uint64_t total = nodes[0] * nodes[1] * nodes[2];
  require(total <= (std::uint64_t{1} << 28), "boundary_surface: grid nodes", static_cast<double>(total),
          "must be at most 2^28 (lower cells_per_axis)");
  auto node = [&](std::uint64_t i, std::uint64_t j, std::uint64_t k) { return i + nodes[0] * (j + nodes[1] * k); };
  auto position = [&](std::uint64_t id) {
    Vec3 x = Vec3::Zero();
    const std::uint64_t ijk[3] = {id % nodes[0], (id / nodes[0]) % nodes[1], id / (nodes[0] * nodes[1])};
    for (int a = 0; a < dim; ++a) x[a] = lo[a] + static_cast<double>(ijk[a]) * h[a];
    return x;
  };
  std::vector<double> f(total);
#pragma omp parallel for schedule(static)
  for (std::int64_t id = 0; id < static_cast<std::int64_t>(total); ++id)
    f[static_cast<std::size_t>(id)] = domain.query(position(static_cast<std::uint64_t>(id))).signed_distance - offset;

  Builder builder(domain, patches, total);
  auto run = [&](const std::uint64_t* g, int count) {
    std::uint64_t gg[4];
    Vec3 x[4];
    double v[4];
    for (int i = 0; i < count; ++i) {
      gg[i] = g[i];
      x[i] = position(g[i]);
      v[i] = f[g[i]];
      if (!std::isfinite(v[i])) return;  // no wall here (periodic or free directions)
    }
    builder.simplex(gg, x, v, count);
  };
  const std::uint64_t m = static_cast<std::uint64_t>(n);
  if (dim == 1) {
    for (std::uint64_t i = 0; i < m; ++i) {
      const std::uint64_t g[2] = {i, i + 1};
      run(g, 2);
    }
  } else if (dim == 2) {
    for (std::uint64_t j = 0; j < m; ++j)
      for (std::uint64_t i = 0; i < m; ++i) {
        const std::uint64_t a = node(i, j, 0), b = node(i + 1, j, 0), c = node(i + 1, j + 1, 0), d = node(i, j + 1, 0);
        const std::uint64_t t1[3] = {a, b, c}, t2[3] = {a, c, d};
        run(t1, 3);
        run(t2, 3);
      }
  } else {
    // Kuhn's 6 tetrahedra: from corner 000 to 111, stepping along the axes
    // in each of the 6 orders; neighbouring cubes then share face diagonals.
    static const int kOrders[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    for (std::uint64_t k = 0; k < m; ++k)
      for (std::uint64_t j = 0; j < m; ++j)
        for (std::uint64_t i = 0; i < m; ++i)
          for (const auto& order : kOrders) {
            std::uint64_t c[3] = {i, j, k};
            std::uint64_t g[4];
            g[0] = node(c[0], c[1], c[2]);
            for (int s = 0; s < 3; ++s) {
              ++c[order[s]];
              g[s + 1] = node(c[0], c[1], c[2]);
            }
            run(g, 4);
          }
  }
  return builder.take();
}

double surface_measure(const SurfaceMesh& mesh, int patch) {
  const auto& P = mesh.points;
  const std::size_t per = static_cast<std::size_t>(mesh.dim);
  double sum = 0.0;
  for (std::size_t c = 0; c < mesh.num_cells(); ++c) {
    if (patch >= -1 && mesh.patch[c] != patch) continue;
    const std::int64_t* v = &mesh.cells[c * per];
    if (mesh.dim == 3)
      sum += 0.5 * (P[v[1]] - P[v[0]]).cross(P[v[2]] - P[v[0]]).norm();
    else if (mesh.dim == 2)
      sum += (P[v[1]] - P[v[0]]).norm();
    else
      sum += 1.0;
  }
  return sum;
}

double surface_measure(const SurfaceMesh& mesh) { return surface_measure(mesh, -2); }

std::string surface_vtp(const SurfaceMesh& mesh) {
  require(mesh.dim >= 1 && mesh.dim <= 3, "surface_vtp: mesh.dim", mesh.dim, "must be 1, 2 or 3");
  const std::size_t per = static_cast<std::size_t>(mesh.dim), nc = mesh.num_cells(), np = mesh.points.size();
  require(mesh.cells.size() == per * nc, "surface_vtp: mesh.cells size", static_cast<double>(mesh.cells.size()),
          fmt::format("must be dim * number of patch ids ({})", per * nc));
  // A display mesh: Float32 coordinates and, when they fit, Int32 indices
  // keep the file small (a 3-D file is ~26 bytes per triangle instead of 48).
  std::vector<float> pos(3 * np);
  for (std::size_t p = 0; p < np; ++p)
    for (int k = 0; k < 3; ++k) pos[3 * p + static_cast<std::size_t>(k)] = static_cast<float>(mesh.points[p][k]);
  for (std::int64_t v : mesh.cells)
    require(v >= 0 && static_cast<std::size_t>(v) < np, "surface_vtp: point index", static_cast<double>(v),
            fmt::format("must be in [0, {})", np));
  const bool narrow = per * nc <= static_cast<std::size_t>(INT32_MAX);  // point indices are below per * nc too
  std::vector<std::int64_t> offsets(narrow ? 0 : nc);
  std::vector<std::int32_t> offsets32(narrow ? nc : 0), cells32;
  for (std::size_t c = 0; c < nc; ++c) {
    if (narrow)
      offsets32[c] = static_cast<std::int32_t>((c + 1) * per);
    else
      offsets[c] = static_cast<std::int64_t>((c + 1) * per);
  }
  if (narrow) cells32.assign(mesh.cells.begin(), mesh.cells.end());
  std::vector<std::int32_t> patch(mesh.patch.begin(), mesh.patch.end());

  const char* section = mesh.dim == 3 ? "Polys" : mesh.dim == 2 ? "Lines" : "Verts";
  detail::VtkArrays arrays;
  std::string xml;
  xml += "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  xml += "  <PolyData>\n";
  xml += fmt::format(
      "    <Piece NumberOfPoints=\"{}\" NumberOfVerts=\"{}\" NumberOfLines=\"{}\" NumberOfStrips=\"0\" "
      "NumberOfPolys=\"{}\">\n",
      np, mesh.dim == 1 ? nc : 0, mesh.dim == 2 ? nc : 0, mesh.dim == 3 ? nc : 0);
  xml += "      <CellData Scalars=\"patch\">\n";
  xml += arrays.array("patch", patch, 1, 8);
  xml += "      </CellData>\n";
  xml += "      <Points>\n";
  xml += arrays.array("position", pos, 3, 8);
  xml += "      </Points>\n";
  xml += fmt::format("      <{}>\n", section);
  xml += narrow ? arrays.array("connectivity", cells32, 1, 8) : arrays.array("connectivity", mesh.cells, 1, 8);
  xml += narrow ? arrays.array("offsets", offsets32, 1, 8) : arrays.array("offsets", offsets, 1, 8);
  xml += fmt::format("      </{}>\n", section);
  xml += "    </Piece>\n";
  xml += "  </PolyData>\n";
  xml += arrays.appended_section();
  xml += "</VTKFile>\n";
  return xml;
}

}  // namespace otfp
