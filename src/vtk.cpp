#include "otfp/vtk.hpp"

#include <fmt/format.h>

#include "vtk_xml.hpp"

namespace otfp {

namespace detail {

std::string vtk_array_tag(const char* type, const std::string& name, int components, std::uint64_t offset,
                          int indent) {
  std::string tag = fmt::format("{:{}}<DataArray type=\"{}\" Name=\"{}\"", "", indent, type, name);
  if (components != 1) tag += fmt::format(" NumberOfComponents=\"{}\"", components);
  return tag + fmt::format(" format=\"appended\" offset=\"{}\"/>\n", offset);
}

std::string VtkArrays::appended_section() const {
  return "  <AppendedData encoding=\"raw\">\n   _" + data_ + "\n  </AppendedData>\n";
}

}  // namespace detail

std::string vtp_document(const ParticleSet& ps, double t, const std::vector<std::int32_t>& region,
                         const std::vector<double>& density) {
  const std::size_t n = ps.size();
  // With zero particles an empty vector is one value per particle: the
  // optional arrays are then declared too.
  const bool with_region = n == 0 || !region.empty();
  const bool with_density = n == 0 || !density.empty();
  require(!with_region || region.size() == n, "vtp_document: region size", static_cast<double>(region.size()),
          fmt::format("must be 0 or the number of particles ({})", n));
  require(!with_density || density.size() == n, "vtp_document: density size", static_cast<double>(density.size()),
          fmt::format("must be 0 or the number of particles ({})", n));

  std::vector<double> pos(3 * n), beta(n), age(n);
  std::vector<std::int64_t> id(ps.ids().begin(), ps.ids().end()), conn(n), offsets(n);
  for (std::size_t p = 0; p < n; ++p) {
    for (int k = 0; k < 3; ++k) pos[3 * p + k] = ps.positions()[p][k];
    beta[p] = ps.beta(p);
    age[p] = t - ps.birth_times()[p];
    conn[p] = static_cast<std::int64_t>(p);
    offsets[p] = static_cast<std::int64_t>(p + 1);
  }

  detail::VtkArrays arrays;
  std::string xml;
  xml += "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  xml += "  <PolyData>\n";
  xml += "    <FieldData>\n";
  xml += fmt::format(
      "      <DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">{}</DataArray>\n", t);
  xml += "    </FieldData>\n";
  xml += fmt::format(
      "    <Piece NumberOfPoints=\"{0}\" NumberOfVerts=\"{0}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" "
      "NumberOfPolys=\"0\">\n",
      n);
  xml += "      <PointData Scalars=\"age\">\n";
  xml += arrays.array("mass", ps.masses(), 1, 8);
  xml += arrays.array("beta", beta, 1, 8);
  xml += arrays.array("width_s", ps.widths(), 1, 8);
  xml += arrays.array("age", age, 1, 8);
  xml += arrays.array("id", id, 1, 8);
  if (with_region) xml += arrays.array("region", region, 1, 8);
  if (with_density) xml += arrays.array("density", density, 1, 8);
  xml += "      </PointData>\n";
  xml += "      <Points>\n";
  xml += arrays.array("position", pos, 3, 8);
  xml += "      </Points>\n";
  xml += "      <Verts>\n";
  xml += arrays.array("connectivity", conn, 1, 8);
  xml += arrays.array("offsets", offsets, 1, 8);
  xml += "      </Verts>\n";
  xml += "    </Piece>\n";
  xml += "  </PolyData>\n";
  xml += arrays.appended_section();
  xml += "</VTKFile>\n";
  return xml;
}

namespace {
// A file name as an XML attribute value.
std::string xml_escaped(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}
}  // namespace

std::string pvd_document(const std::vector<std::pair<double, std::string>>& entries) {
  std::string xml = "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n";
  for (const auto& [t, file] : entries)
    xml += fmt::format("    <DataSet timestep=\"{}\" group=\"\" part=\"0\" file=\"{}\"/>\n", t, xml_escaped(file));
  xml += "  </Collection>\n</VTKFile>\n";
  return xml;
}

std::string pvtp_document(const std::vector<std::string>& pieces) {
  // The arrays of vtp_document's pieces, region and density included.
  std::string xml = "<?xml version=\"1.0\"?>\n";
  xml += "<VTKFile type=\"PPolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n";
  xml += "  <PPolyData GhostLevel=\"0\">\n";
  xml += "    <PPointData Scalars=\"age\">\n";
  for (const char* name : {"mass", "beta", "width_s", "age"})
    xml += fmt::format("      <PDataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"1\"/>\n", name);
  xml += "      <PDataArray type=\"Int64\" Name=\"id\" NumberOfComponents=\"1\"/>\n";
  xml += "      <PDataArray type=\"Int32\" Name=\"region\" NumberOfComponents=\"1\"/>\n";
  xml += "      <PDataArray type=\"Float64\" Name=\"density\" NumberOfComponents=\"1\"/>\n";
  xml += "    </PPointData>\n";
  xml += "    <PPoints>\n      <PDataArray type=\"Float64\" Name=\"position\" NumberOfComponents=\"3\"/>\n    </PPoints>\n";
  for (const std::string& piece : pieces) xml += fmt::format("    <Piece Source=\"{}\"/>\n", xml_escaped(piece));
  xml += "  </PPolyData>\n</VTKFile>\n";
  return xml;
}

namespace {
// A file name as Python source: os.fsdecode of a bytes literal, so that any
// bytes (quotes, backslashes, newlines, non-UTF-8 names) survive.
std::string python_path(const std::string& s) {
  std::string out = "os.fsdecode(b\"";
  for (unsigned char c : s) {
    if (c >= 0x20 && c < 0x7f && c != '"' && c != '\\')
      out += static_cast<char>(c);
    else
      out += fmt::format("\\x{:02x}", c);
  }
  return out + "\")";
}
}  // namespace

std::string paraview_script(const std::string& particles_pvd, const std::string& domain_file,
                            const std::string& run_dir) {
  std::string py;
  py += "# ParaView view of an otfp run, written by otfp (docs/outputs.md): the particles\n"
        "# coloured by their blob density at the last snapshot, the domain as a\n"
        "# translucent outline.\n"
        "#   paraview --script=view.py                  interactive\n"
        "#   pvpython view.py --screenshot view.png     saves the view and exits\n"
        "# (without a display: xvfb-run -a pvpython view.py --screenshot view.png)\n"
        "import os\n"
        "import sys\n"
        "\n"
        "from paraview.simple import (ColorBy, GetActiveViewOrCreate, GetAnimationScene, PVDReader, Render,\n"
        "                             SaveScreenshot, Show, XMLPolyDataReader)\n"
        "\n";
  py += "PARTICLES = " + python_path(particles_pvd) + "\n";
  py += "DOMAIN = " + python_path(domain_file) + "  # empty: no domain surface (free space, periodic box)\n";
  py += "RUN_DIR = " + python_path(run_dir) + "  # where otfp wrote the run\n";
  py += R"py(

def run_directory():
    """This script's directory; ParaView's GUI runs --script without __file__."""
    candidates = [RUN_DIR, os.getcwd()]
    if "__file__" in globals():
        candidates.insert(0, os.path.dirname(os.path.abspath(__file__)))
    for d in candidates:
        if os.path.isfile(os.path.join(d, PARTICLES)):
            return d
    sys.exit(f"view.py: {PARTICLES} is neither beside this script, in {RUN_DIR} nor in the current directory")


def show_run(d):
    view = GetActiveViewOrCreate("RenderView")
    particles = PVDReader(registrationName="particles", FileName=os.path.join(d, PARTICLES))
    times = particles.TimestepValues  # a list, or one number for one snapshot
    times = list(times) if hasattr(times, "__len__") else [times]
    if times:
        # The last snapshot. (Not UpdateAnimationUsingDataTimeSteps(): it
        # hangs `paraview --script` at start-up; the GUI snaps to the data's
        # times by itself.)
        GetAnimationScene().AnimationTime = times[-1]
    points = Show(particles, view)
    points.SetRepresentationType("Points")
    points.PointSize = 5
    points.RenderPointsAsSpheres = 1
    ColorBy(points, ("POINTS", "density"))
    points.RescaleTransferFunctionToDataRange(True, False)
    points.SetScalarBarVisibility(view, True)
    if DOMAIN and os.path.isfile(os.path.join(d, DOMAIN)):
        domain = XMLPolyDataReader(registrationName="domain", FileName=[os.path.join(d, DOMAIN)])
        outline = Show(domain, view)
        ColorBy(outline, None)
        outline.AmbientColor = [0.55, 0.55, 0.55]
        outline.DiffuseColor = [0.55, 0.55, 0.55]
        outline.Opacity = 0.2
    bounds = particles.GetDataInformation().GetBounds()
    if bounds[4] == bounds[5]:  # a 1-D or 2-D run: points in the plane z = 0
        view.InteractionMode = "2D"
    view.ResetCamera()
    Render(view)
    return view


def main(argv):
    view = show_run(run_directory())
    if "--screenshot" in argv:
        i = argv.index("--screenshot")
        if i + 1 >= len(argv):
            sys.exit("view.py: --screenshot needs a file name")
        SaveScreenshot(argv[i + 1], view, ImageResolution=[1000, 800], FontScaling="Do not scale fonts")


main(sys.argv)
)py";
  return py;
}

}  // namespace otfp
