#pragma once
// VTK XML output for ParaView: the particles as PolyData (.vtp, raw appended
// binary, little-endian, UInt64 block headers) and the time collection (.pvd).
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "otfp/particles.hpp"

namespace otfp {

// PolyData of the particles at time t: the points, one vertex cell per
// particle, field data TimeValue = t and point data
//   mass, beta, width_s, age = t - birth_time, id, region, density.
// `region` (Int32, e.g. inside/buffer/elsewhere) and `density` (the blob
// density at each particle, computed by the caller) are optional: empty
// omits the array, otherwise it needs one value per particle
// (InvalidArgument). With zero particles every array, region and density
// included, is still declared (a zero-byte block), so that a series that
// starts empty lists its arrays from the first snapshot on.
std::string vtp_document(const ParticleSet& particles, double t, const std::vector<std::int32_t>& region = {},
                         const std::vector<double>& density = {});

// ParaView collection (.pvd) of (time, file) entries, part 0. A non-empty
// `static_file` (e.g. the domain surface of otfp/surface.hpp) is added as
// part 1 at every time, so ParaView shows it throughout the series.
std::string pvd_document(const std::vector<std::pair<double, std::string>>& entries,
                         const std::string& static_file = {});

}  // namespace otfp
