#pragma once
// The boundary of a Domain as a mesh, for display (ParaView) next to the
// particles: the iso-surface signed_distance = offset, extracted from samples
// of Domain::query() on a grid, so any domain gets one without new code.
#include <cstdint>
#include <string>
#include <vector>

#include "otfp/geometry.hpp"

namespace otfp {

struct SurfaceMesh {
  int dim = 3;                        // of the domain: cells have `dim` points each
  std::vector<Vec3> points;
  std::vector<std::int64_t> cells;    // dim point indices per cell: triangles (3-D),
                                      // segments (2-D), single points (1-D)
  std::vector<int> patch;             // patch id of each cell (at its centroid)
  std::size_t num_cells() const { return patch.size(); }
};

// The surface signed_distance(x) = offset of `domain` (offset 0: the
// boundary; offset b > 0: the outer surface of the layer of thickness b).
// The grid covers the bounding box grown by max(offset, 0) and one cell on
// each side with `cells_per_axis` cells per axis (>= 4); the surface is
// extracted by marching tetrahedra (3-D; each cube cut into 6 tetrahedra
// along its main diagonal) or marching triangles (2-D; each square cut into
// two, which removes the ambiguous saddle case of marching squares), with
// crossings placed by linear interpolation of the signed distance, and is
// oriented with its normals pointing outward. Cells whose patch is not in
// `patches` are dropped (empty: keep all). Domains without a boundary
// (is_periodic() or no patches, e.g. free space) give an empty mesh, as do
// grid cells with a non-finite signed distance at a corner.
SurfaceMesh boundary_surface(const Domain& domain, double offset, int cells_per_axis,
                             const std::vector<int>& patches = {});

// Total (dim-1)-measure of the cells: area (3-D), length (2-D) or the number
// of points (1-D), as Domain::patch_area() counts it.
double surface_measure(const SurfaceMesh& mesh);
// The same for the cells of one patch.
double surface_measure(const SurfaceMesh& mesh, int patch);

// VTK XML PolyData of the mesh (Polys, Lines or Verts by dimension), cell
// data `patch` (Int32), raw appended binary like vtp_document(). A display
// file: Float32 points, and Int32 connectivity and offsets when they fit.
std::string surface_vtp(const SurfaceMesh& mesh);

}  // namespace otfp
