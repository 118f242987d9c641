#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "otfp/particle_io.hpp"
#include "otfp/vtk.hpp"
#include "test_support.hpp"

using namespace otfp;

namespace {

std::filesystem::path scratch(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() / ("otfp_particle_io_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return dir / name;
}

std::filesystem::path write(const std::string& name, const std::string& content) {
  const auto path = scratch(name);
  std::ofstream(path, std::ios::binary) << content;
  return path;
}

// A cloud whose values need all 17 significant digits, with ids that are not 0..n-1.
ParticleSet awkward_cloud(int dim) {
  ParticleSet ps = otfp::testing::random_cloud(dim, 50, -1.0, 1.0, 0.05, 0.5, 1e-3, 77);
  Rng rng(3);
  for (std::size_t p = 0; p < ps.size(); ++p) ps.birth_times()[p] = rng.uniform(0.0, 1.0) / 3.0;
  ps.remove_indices({0, 7, 11});
  ps.add(Vec3(1.0 / 3.0, 0.0, 0.0), 1e-300, 1e300, -2.5e-7);  // extreme but finite
  return ps;
}

void expect_same(const ParticleSet& a, const ParticleSet& b, bool exact_birth) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t p = 0; p < a.size(); ++p) {
    const auto q = b.index_of(a.ids()[p]);
    ASSERT_GE(q, 0) << "id " << a.ids()[p];
    EXPECT_EQ(std::memcmp(a.positions()[p].data(), b.positions()[q].data(), 3 * sizeof(double)), 0) << p;
    EXPECT_EQ(a.widths()[p], b.widths()[q]) << p;
    EXPECT_EQ(a.masses()[p], b.masses()[q]) << p;
    if (exact_birth) {
      EXPECT_EQ(a.birth_times()[p], b.birth_times()[q]) << p;
    }
  }
  EXPECT_EQ(b.next_id(), *std::max_element(a.ids().begin(), a.ids().end()) + 1);
}

std::string message_of(const std::filesystem::path& file, int dim) {
  try {
    read_particles(file, dim);
  } catch (const InvalidArgument& e) {
    return e.what();
  }
  return "(no exception)";
}

}  // namespace

TEST(ParticleIo, CsvHasTheCommandLineLayout) {
  ParticleSet ps(2);
  ps.add_with_id(4, Vec3(0.5, -1.25, 0.0), 0.5, 2.0, 0.125);
  ps.add_with_id(9, Vec3(1e-7, 3e20, 0.0), 0.25, 1.0 / 3.0, 0.0);
  EXPECT_EQ(particles_csv(ps, {1, 2}),
            "id,x,y,z,width_s,beta,mass,birth_time,region\n"
            "4,0.5,-1.25,0,0.5,4,2,0.125,1\n"
            "9,1e-07,3e+20,0,0.25,16,0.3333333333333333,0,2\n");
  EXPECT_EQ(particles_csv(ps).substr(particles_csv(ps).size() - 2), "0\n") << "empty region: column 0";
  EXPECT_THROW(particles_csv(ps, {1}), InvalidArgument);
}

TEST(ParticleIo, CsvRoundTripIsExact) {
  for (int dim : {1, 2, 3}) {
    const ParticleSet ps = awkward_cloud(dim);
    const auto file = write("round_trip.csv", particles_csv(ps));
    const ParticleSet back = read_particles(file, dim);
    expect_same(ps, back, true);
    EXPECT_EQ(back.dim(), dim);
    EXPECT_EQ(particles_csv(back), particles_csv(ps)) << "same order, same bytes";
  }
}

TEST(ParticleIo, CsvWithoutIdsGetsRowOrderIdsAndBetaGivesTheWidth) {
  const auto file = write("minimal.csv", "mass,beta,x,birth_time\n2,4,0.5,1\n\n3,100,-1,0\n");
  const ParticleSet ps = read_particles(file, 1);
  ASSERT_EQ(ps.size(), 2u);
  EXPECT_EQ(ps.ids()[0], 0);
  EXPECT_EQ(ps.ids()[1], 1);
  EXPECT_EQ(ps.widths()[0], 0.5);
  EXPECT_DOUBLE_EQ(ps.widths()[1], 0.1);
  EXPECT_EQ(ps.masses()[1], 3.0);
  EXPECT_EQ(ps.positions()[1], Vec3(-1.0, 0.0, 0.0));
  EXPECT_EQ(ps.birth_times()[0], 1.0);
}

TEST(ParticleIo, VtpRoundTrip) {
  for (int dim : {1, 3}) {
    const ParticleSet ps = awkward_cloud(dim);
    const double t = 0.75;
    const auto file = write("round_trip.vtp", vtp_document(ps, t, std::vector<std::int32_t>(ps.size(), 1)));
    const ParticleSet back = read_particles(file, dim);
    expect_same(ps, back, false);
    // birth = TimeValue - age: exact up to the rounding of t - birth and back.
    for (std::size_t p = 0; p < ps.size(); ++p)
      EXPECT_NEAR(back.birth_times()[p], ps.birth_times()[p], 4e-16 * (1.0 + std::abs(t))) << p;
  }
  const auto empty = write("empty.vtp", vtp_document(ParticleSet(2), 0.0));
  EXPECT_EQ(read_particles(empty, 2).size(), 0u) << "a zero-particle snapshot reads back empty";
}

TEST(ParticleIo, BadFilesAreRejectedWithOneLine) {
  const std::string dir = scratch("").string();
  auto expect = [&](const std::string& name, const std::string& content, const std::string& message, int dim = 3) {
    const auto file = write(name, content);
    EXPECT_EQ(message_of(file, dim), "particle file" + message) << name;
  };
  EXPECT_EQ(message_of(scratch("absent.csv"), 3), "particle file = '" + scratch("absent.csv").string() + "': does not exist");
  EXPECT_EQ(message_of(scratch(""), 3), "particle file = '" + dir + "': is a directory, not a file");
  const std::string p = dir;
  expect("empty.csv", "\n \n", " = '" + p + "empty.csv': is empty");
  expect("particles.txt", "x,mass\n", " = '" + p + "particles.txt': must end in .csv or .vtp");
  expect("nowidth.csv", "x,y,z,mass\n0,0,0,1\n",
         " '" + p + "nowidth.csv' line 1 (header) = 'x,y,z,mass': has no column 'width_s' or 'beta'");
  expect("noz.csv", "x,y,mass,width_s\n0,0,1,1\n", " '" + p + "noz.csv' line 1 (header) = 'x,y,mass,width_s': has no column 'z'");
  expect("text.csv", "x,mass,width_s\n0,1,1\n\n1,one,1\n", " '" + p + "text.csv' line 4 column mass = 'one': must be a number", 1);
  expect("short.csv", "x,mass,width_s\n0,1\n", " '" + p + "short.csv' line 2 = '0,1': has 2 fields, the header 3", 1);
  expect("inf.csv", "x,mass,width_s\ninf,1,1\n", " '" + p + "inf.csv' line 2 column x = 'inf': must be finite", 1);
  expect("width.csv", "x,mass,width_s\n0,1,0\n", " '" + p + "width.csv' line 2 column width_s = '0': must be finite and > 0", 1);
  expect("beta.csv", "x,mass,beta\n0,1,-4\n", " '" + p + "beta.csv' line 2 column beta = '-4': must be finite and > 0", 1);
  expect("mass.csv", "x,mass,width_s\n0,-1,1\n", " '" + p + "mass.csv' line 2 column mass = '-1': must be finite and > 0", 1);
  expect("dup.csv", "id,x,mass,width_s\n3,0,1,1\n4,0,1,1\n3,0,1,1\n",
         " '" + p + "dup.csv' line 4 column id = '3': duplicates the id on line 2", 1);
  expect("badid.csv", "id,x,mass,width_s\n1.5,0,1,1\n", " '" + p + "badid.csv' line 2 column id = '1.5': must be an integer >= 0", 1);
  expect("negid.csv", "id,x,mass,width_s\n-2,0,1,1\n", " '" + p + "negid.csv' line 2 column id = '-2': must be >= 0", 1);
  expect("beyond.csv", "x,y,z,mass,width_s\n0,0,0,1,1\n0,0,0.5,1,1\n",
         " '" + p + "beyond.csv' line 3 column z = '0.5': must be 0 for dim = 2", 2);

  ParticleSet ps(2);
  ps.add(Vec3(1.0, 2.0, 0.0), 0.5, 1.0);
  ps.add(Vec3(3.0, 4.0, 0.0), 0.5, 1.0);
  const std::string doc = vtp_document(ps, 0.0);
  expect("beyond.vtp", doc, " '" + p + "beyond.vtp' array 'position.y' point 0 = '2': must be 0 for dim = 1", 1);
  // Cut inside the last array (Verts offsets): the arrays read before it are whole.
  const std::size_t cut = doc.find("</AppendedData>") - 20;
  const std::string pos_tag = "Name=\"position\" NumberOfComponents=\"3\" format=\"appended\" offset=\"";
  ASSERT_NE(doc.find(pos_tag), std::string::npos);
  expect("truncated.vtp", doc.substr(0, doc.find("_", doc.find("<AppendedData")) + 40),
         " '" + p + "truncated.vtp' array 'position' offset = '" +
             doc.substr(doc.find(pos_tag) + pos_tag.size(),
                        doc.find('"', doc.find(pos_tag) + pos_tag.size()) - doc.find(pos_tag) - pos_tag.size()) +
             "': is past the end of the data (39 bytes): the file is truncated",
         2);
  EXPECT_EQ(read_particles(write("cut_tail.vtp", doc.substr(0, cut)), 2).size(), 2u)
      << "the Verts arrays are not needed to read the particles";
  expect("nomass.vtp", std::string(doc).replace(doc.find("Name=\"mass\""), 11, "Name=\"mast\""),
         " '" + p + "nomass.vtp' DataArray = 'mass': is required but missing", 2);
  expect("notvtk.vtp", "hello", " '" + p + "notvtk.vtp' = 'no <VTKFile> element': must be VTK XML PolyData");
  // Ids beyond 2^62 (id + 1 would overflow later).
  expect("bigid.csv", "id,x,mass,width_s\n9223372036854775807,0,1,1\n",
         " '" + p + "bigid.csv' line 2 column id = '9223372036854775807': must be <= 2^62 = 4611686018427387904", 1);
  // A point count the file cannot hold (24 x 2^61 wraps to 0 bytes).
  const std::string np = "NumberOfPoints=\"2\"";
  ASSERT_NE(doc.find(np), std::string::npos);
  const std::string huge = std::string(doc).replace(doc.find(np), np.size(), "NumberOfPoints=\"2305843009213693952\"");
  expect("huge.vtp", huge,
         " '" + p + "huge.vtp' Piece NumberOfPoints = '2305843009213693952': more points than the file's " +
             std::to_string(huge.size()) + " bytes can hold (24 bytes of position each)",
         2);
  // Two columns of one name: which one is meant is not known.
  expect("twox.csv", "x,mass,x,width_s\n0,1,5,1\n",
         " '" + p + "twox.csv' line 1 (header) = 'x,mass,x,width_s': has the column 'x' twice", 1);
}

// Not a regular file: a FIFO would block the read and a device such as
// /dev/zero never ends; both are refused at once, naming what the path is.
TEST(ParticleIo, NonRegularFilesAreRefused) {
  const auto fifo = scratch("fifo.csv");
  std::filesystem::remove(fifo);
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_EQ(message_of(fifo, 3), "particle file = '" + fifo.string() + "': is not a regular file (a FIFO)");
  const auto zero = scratch("zero.vtp");
  std::filesystem::remove(zero);
  std::filesystem::create_symlink("/dev/zero", zero);
  EXPECT_EQ(message_of(zero, 3), "particle file = '" + zero.string() + "': is not a regular file (a device)");
  std::filesystem::remove(fifo);
  std::filesystem::remove(zero);
}
