#include <gtest/gtest.h>

#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "otfp/vtk.hpp"

using namespace otfp;

namespace {

std::size_t count(const std::string& s, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t p = s.find(what); p != std::string::npos; p = s.find(what, p + 1)) ++n;
  return n;
}

// Checks that the XML before the appended data nests properly: every start
// tag is closed by its end tag (or is self-closing). Returns "" or the problem.
std::string nesting_problem(const std::string& doc) {
  const std::size_t end = doc.find("_", doc.find("<AppendedData"));
  const std::string xml = end == std::string::npos ? doc : doc.substr(0, end);
  std::vector<std::string> open;
  for (std::size_t p = xml.find('<'); p != std::string::npos; p = xml.find('<', p + 1)) {
    const std::size_t q = xml.find('>', p);
    if (q == std::string::npos) return "unterminated tag";
    const std::string tag = xml.substr(p + 1, q - p - 1);
    if (tag[0] == '?') continue;
    const std::string name = tag.substr(tag[0] == '/' ? 1 : 0, tag.find_first_of(" />", 1) - (tag[0] == '/' ? 1 : 0));
    if (tag[0] == '/') {
      if (open.empty() || open.back() != name) return "unexpected </" + name + ">";
      open.pop_back();
    } else if (tag.back() != '/') {
      open.push_back(name);
    }
  }
  if (end != std::string::npos) return open.size() == 2 && open.back() == "AppendedData" ? "" : "bad appended nesting";
  return open.empty() ? "" : "unclosed <" + open.back() + ">";
}

// Appended arrays by name: (type, byte count, bytes).
std::map<std::string, std::pair<std::string, std::string>> appended(const std::string& doc) {
  std::map<std::string, std::pair<std::string, std::string>> out;
  const std::size_t start = doc.find("_", doc.find("<AppendedData")) + 1;
  for (std::size_t p = doc.find("<DataArray"); p < start; p = doc.find("<DataArray", p + 1)) {
    const std::string tag = doc.substr(p, doc.find('>', p) - p);
    auto attr = [&](const std::string& key) {
      const std::size_t a = tag.find(" " + key + "=\"");
      if (a == std::string::npos) return std::string();
      const std::size_t b = a + key.size() + 3;
      return tag.substr(b, tag.find('"', b) - b);
    };
    if (attr("format") != "appended") continue;
    const std::size_t off = start + std::stoull(attr("offset"));
    std::uint64_t bytes = 0;
    std::memcpy(&bytes, doc.data() + off, 8);
    out[attr("Name")] = {attr("type"), doc.substr(off + 8, bytes)};
  }
  return out;
}

template <class T>
std::vector<T> values(const std::string& raw) {
  std::vector<T> v(raw.size() / sizeof(T));
  std::memcpy(v.data(), raw.data(), raw.size());
  return v;
}

}  // namespace

TEST(Vtk, VtpHoldsEveryPointArray) {
  ParticleSet ps(3);
  ps.add(Vec3(1.0, 2.0, 3.0), 0.5, 2.0, 0.25);
  ps.add_with_id(10, Vec3(-1.0, 0.0, 0.5), 0.25, 1.0, 0.5);
  const std::string doc = vtp_document(ps, 1.5, {0, 2}, {3.5, 7.0});
  EXPECT_EQ(nesting_problem(doc), "");
  EXPECT_NE(doc.find("NumberOfPoints=\"2\" NumberOfVerts=\"2\""), std::string::npos);
  EXPECT_NE(doc.find("Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">1.5<"), std::string::npos);
  const auto a = appended(doc);
  EXPECT_EQ(a.size(), 10u) << "7 point arrays, position, connectivity, offsets";
  EXPECT_EQ(values<double>(a.at("mass").second), (std::vector<double>{2.0, 1.0}));
  EXPECT_EQ(values<double>(a.at("beta").second), (std::vector<double>{4.0, 16.0}));
  EXPECT_EQ(values<double>(a.at("width_s").second), (std::vector<double>{0.5, 0.25}));
  EXPECT_EQ(values<double>(a.at("age").second), (std::vector<double>{1.25, 1.0}));
  EXPECT_EQ(values<std::int64_t>(a.at("id").second), (std::vector<std::int64_t>{0, 10}));
  EXPECT_EQ(a.at("region").first, "Int32");
  EXPECT_EQ(values<std::int32_t>(a.at("region").second), (std::vector<std::int32_t>{0, 2}));
  EXPECT_EQ(values<double>(a.at("density").second), (std::vector<double>{3.5, 7.0}));
  EXPECT_EQ(values<double>(a.at("position").second), (std::vector<double>{1, 2, 3, -1, 0, 0.5}));
  EXPECT_EQ(values<std::int64_t>(a.at("offsets").second), (std::vector<std::int64_t>{1, 2}));
}

TEST(Vtk, OptionalArraysAreOmittedWhenEmptyAndCheckedOtherwise) {
  ParticleSet ps(1);
  ps.add(Vec3::Zero(), 1.0, 1.0);
  const auto a = appended(vtp_document(ps, 0.0));
  EXPECT_EQ(a.count("region"), 0u);
  EXPECT_EQ(a.count("density"), 0u);
  EXPECT_EQ(a.count("width_s"), 1u);
  try {
    vtp_document(ps, 0.0, {}, {1.0, 2.0});
    ADD_FAILURE() << "density of the wrong size accepted";
  } catch (const InvalidArgument& e) {
    EXPECT_STREQ(e.what(), "vtp_document: density size = 2: must be 0 or the number of particles (1)");
  }
  EXPECT_THROW(vtp_document(ps, 0.0, {0, 1}), InvalidArgument);
}

TEST(Vtk, ZeroParticleDocumentDeclaresEveryArray) {
  const std::string doc = vtp_document(ParticleSet(3), 0.0);
  EXPECT_EQ(nesting_problem(doc), "");
  EXPECT_NE(doc.find("NumberOfPoints=\"0\" NumberOfVerts=\"0\""), std::string::npos);
  const std::string point_data = doc.substr(doc.find("<PointData"), doc.find("</PointData>") - doc.find("<PointData"));
  for (const char* name : {"mass", "beta", "width_s", "age", "id", "region", "density"})
    EXPECT_NE(point_data.find(std::string("Name=\"") + name + "\" format=\"appended\""), std::string::npos) << name;
  const auto a = appended(doc);
  EXPECT_EQ(a.size(), 10u) << "7 point arrays, position, connectivity, offsets";
  for (const auto& [name, block] : a) EXPECT_TRUE(block.second.empty()) << name << ": a zero byte count";
  // The appended section holds exactly the ten zero counts.
  const std::size_t start = doc.find("_", doc.find("<AppendedData")) + 1;
  EXPECT_EQ(doc.substr(start + 10 * 8), "\n  </AppendedData>\n</VTKFile>\n");
}

TEST(Vtk, PvdListsOnlyTheParticles) {
  // A domain surface listed as a second part is drawn opaque by ParaView's
  // defaults and hides every particle (issue 23): the collection holds the
  // snapshots alone, one part, file names escaped.
  const std::vector<std::pair<double, std::string>> entries = {{0.0, "p_0.vtp"}, {0.5, "p & <1>.vtp"}};
  const std::string pvd = pvd_document(entries);
  EXPECT_EQ(nesting_problem(pvd), "");
  EXPECT_EQ(count(pvd, "<DataSet "), 2u);
  EXPECT_EQ(count(pvd, "part=\"0\""), 2u);
  EXPECT_NE(pvd.find("<DataSet timestep=\"0.5\" group=\"\" part=\"0\" file=\"p &amp; &lt;1&gt;.vtp\"/>"),
            std::string::npos);
}

TEST(Vtk, ParaviewScriptOpensTheRunsFiles) {
  const std::string py = paraview_script("particles.pvd", "domain.vtp", "/runs/a \"b\"\\c\n\xff");
  EXPECT_NE(py.find("PARTICLES = os.fsdecode(b\"particles.pvd\")\n"), std::string::npos);
  EXPECT_NE(py.find("DOMAIN = os.fsdecode(b\"domain.vtp\")"), std::string::npos);
  // Quotes, backslashes, control and non-UTF-8 bytes as \xNN escapes of a bytes literal.
  EXPECT_NE(py.find("RUN_DIR = os.fsdecode(b\"/runs/a \\x22b\\x22\\x5cc\\x0a\\xff\")"), std::string::npos);
  EXPECT_NE(py.find("ColorBy(points, (\"POINTS\", \"density\"))"), std::string::npos);
  EXPECT_NE(py.find("outline.Opacity = 0.2"), std::string::npos);
  // Without a domain surface (free space) the script names none.
  EXPECT_NE(paraview_script("particles.pvd", "", ".").find("DOMAIN = os.fsdecode(b\"\")"), std::string::npos);
}
