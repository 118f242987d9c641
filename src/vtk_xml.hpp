#pragma once
// Internal: pieces of the VTK XML documents written by vtk.cpp and surface.cpp.
#include <bit>
#include <cstdint>
#include <string>
#include <vector>

namespace otfp::detail {

static_assert(std::endian::native == std::endian::little, "the VTK writers declare LittleEndian data");

template <class T> constexpr const char* vtk_type_name();
template <> constexpr const char* vtk_type_name<double>() { return "Float64"; }
template <> constexpr const char* vtk_type_name<std::int64_t>() { return "Int64"; }
template <> constexpr const char* vtk_type_name<std::int32_t>() { return "Int32"; }

// The raw appended section: each array is a UInt64 byte count followed by its
// values. With `ascii` set (a document without points), arrays are written
// inline as empty ascii arrays instead, so no offset points into nothing.
class VtkArrays {
 public:
  explicit VtkArrays(bool ascii) : ascii_(ascii) {}

  // The <DataArray .../> element of `values`, indented by `indent` spaces.
  template <class T>
  std::string array(const std::string& name, const std::vector<T>& values, int components, int indent);

  // "<AppendedData>" ... "</AppendedData>\n", or nothing for an ascii document.
  std::string appended_section() const;

 private:
  bool ascii_;
  std::string data_;
};

std::string vtk_array_tag(const char* type, const std::string& name, int components, bool ascii,
                          std::uint64_t offset, int indent);

template <class T>
std::string VtkArrays::array(const std::string& name, const std::vector<T>& values, int components, int indent) {
  const std::uint64_t offset = data_.size();
  if (!ascii_) {
    const std::uint64_t bytes = values.size() * sizeof(T);
    data_.append(reinterpret_cast<const char*>(&bytes), sizeof bytes);
    if (bytes) data_.append(reinterpret_cast<const char*>(values.data()), bytes);
  }
  return vtk_array_tag(vtk_type_name<T>(), name, components, ascii_, offset, indent);
}

}  // namespace otfp::detail
