#pragma once
// Internal: reading a whole input file (a checkpoint, a particle file)
// safely. Not installed.
#include <filesystem>
#include <stdexcept>
#include <string>

namespace otfp::detail {

// Why a file could not be read, without the file's name (callers prefix it).
struct FileReadError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The bytes of `path`, which must be a regular file (a FIFO would block the
// read, a device such as /dev/zero never ends) of at most half this machine's
// memory. Throws FileReadError: "is not a regular file (a FIFO)", "cannot be
// read (<reason>)", "has N bytes, more than half this machine's memory".
std::string read_regular_file(const std::filesystem::path& path);

}  // namespace otfp::detail
