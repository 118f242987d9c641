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
template <> constexpr const char* vtk_type_name<float>() { return "Float32"; }
template <> constexpr const char* vtk_type_name<std::int64_t>() { return "Int64"; }
template <> constexpr const char* vtk_type_name<std::int32_t>() { return "Int32"; }

// The raw appended section: each array is a UInt64 byte count followed by its
// values; an empty array is a zero count, as VTK's own writer stores it.
class VtkArrays {
 public:

  // The <DataArray .../> element of `values`, indented by `indent` spaces.
  template <class T>
  std::string array(const std::string& name, const std::vector<T>& values, int components, int indent);

  // "<AppendedData>" ... "</AppendedData>\n".
  std::string appended_section() const;

 private:
  std::string data_;
};

std::string vtk_array_tag(const char* type, const std::string& name, int components, std::uint64_t offset,
                          int indent);

template <class T>
std::string VtkArrays::array(const std::string& name, const std::vector<T>& values, int components, int indent) {
  const std::uint64_t offset = data_.size();
  const std::uint64_t bytes = values.size() * sizeof(T);
  data_.append(reinterpret_cast<const char*>(&bytes), sizeof bytes);
  if (bytes) data_.append(reinterpret_cast<const char*>(values.data()), bytes);
  return vtk_array_tag(vtk_type_name<T>(), name, components, offset, indent);
}

}  // namespace otfp::detail
