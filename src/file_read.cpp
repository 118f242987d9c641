#include "file_read.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace otfp::detail {

std::string read_regular_file(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) throw FileReadError("cannot be read (" + std::string(std::strerror(errno)) + ")");
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    const char* kind = S_ISDIR(st.st_mode)                            ? "a directory"
                       : S_ISFIFO(st.st_mode)                         ? "a FIFO"
                       : S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ? "a device"
                       : S_ISSOCK(st.st_mode)                         ? "a socket"
                                                                      : "not a file";
    throw FileReadError(std::string("is not a regular file (") + kind + ")");
  }
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  const double memory = pages > 0 && page > 0 ? static_cast<double>(pages) * static_cast<double>(page) : 4e9;
  if (static_cast<double>(st.st_size) > 0.5 * memory) {
    ::close(fd);
    throw FileReadError("has " + std::to_string(st.st_size) + " bytes, more than half this machine's memory");
  }
  std::string bytes(static_cast<std::size_t>(st.st_size), '\0');
  std::size_t got = 0;
  while (got < bytes.size()) {
    const ssize_t n = ::read(fd, bytes.data() + got, bytes.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string why = n == 0 ? "it shrank while read" : std::strerror(errno);
      ::close(fd);
      throw FileReadError("cannot be read (" + why + ")");
    }
    got += static_cast<std::size_t>(n);
  }
  ::close(fd);
  return bytes;
}

}  // namespace otfp::detail
