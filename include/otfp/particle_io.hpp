#pragma once
// Particle files: the CSV the command-line tool writes (particles_final.csv)
// and reading particles back from that CSV or from a .vtp of otfp/vtk.hpp.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "otfp/particles.hpp"

namespace otfp {

// CSV with header "id,x,y,z,width_s,beta,mass,birth_time,region" and one row
// per particle in storage order; numbers are printed in the shortest form that
// reads back to the same double, so read_particles() restores them bit for
// bit (beta = 1 / s^2 is derived and ignored on reading). `region` holds one
// flag per particle, or is empty: then the column is 0 for every particle.
// Throws InvalidArgument for any other size.
std::string particles_csv(const ParticleSet& particles, const std::vector<std::int32_t>& region = {});

// Reads particles in dimension `dim` from
//  - a .csv with a header row naming the columns, in any order:
//      required  x (and y for dim >= 2, z for dim = 3), mass, and width_s or
//                beta (width_s wins when both are given);
//      optional  y, z beyond dim (then they must be 0), id (integers >= 0,
//                no duplicates; without it the ids are 0 .. n-1 in row
//                order), birth_time (default 0); other columns are ignored;
//  - a .vtp written by vtp_document(): position, mass and width_s or beta
//    are required; id, and birth_time = TimeValue - age, are taken when present.
// next_id() of the result is the largest id + 1. Every bad input throws
// InvalidArgument with one line naming the file, the line (CSV) or array
// (VTP), the column, the value and the rule.
ParticleSet read_particles(const std::filesystem::path& file, int dim);

}  // namespace otfp
