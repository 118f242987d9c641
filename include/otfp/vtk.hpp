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

// Parallel VTK (.pvtp) over pieces written by vtp_document with region and
// density (one piece per process of a distributed run; file names relative
// to the .pvtp). ParaView reads it as one data set.
std::string pvtp_document(const std::vector<std::string>& pieces);

// ParaView collection (.pvd) of (time, file) entries, part 0. Only the
// particles: a domain surface listed here as a second part would be drawn
// opaque by ParaView's defaults and hide every particle (issue 23), so it is
// a file of its own that paraview_script() shows translucent.
std::string pvd_document(const std::vector<std::pair<double, std::string>>& entries);

// A ParaView Python script (run with `pvpython view.py`, `paraview
// --script=view.py`, or from ParaView's Python shell) that opens
// `particles_pvd` (a pvd_document) with the particles as points coloured by
// their `density`, at the last time, and, when `domain_file` is not empty,
// that surface (surface_vtp of otfp/surface.hpp) as a translucent grey
// outline. File names are relative to the script's directory; `run_dir` is
// where the script looks when Python does not tell it its own path (ParaView's
// GUI). `pvpython view.py --screenshot FILE.png` saves the view and exits.
std::string paraview_script(const std::string& particles_pvd, const std::string& domain_file,
                            const std::string& run_dir);

}  // namespace otfp
