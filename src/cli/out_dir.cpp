#include "otfp_app/out_dir.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <string>
#include <system_error>
#include <vector>

namespace otfp::app {

namespace fs = std::filesystem;

namespace {

// The files an otfp run writes into its directory (simulation.cpp,
// writers.cpp), and the temporary files ("<name>.tmp<pid>") of one killed
// while writing them.
bool is_run_output(const std::string& name) {
  static const char* const fixed[] = {"series.csv",      "timing.csv",          "summary.json",
                                      "config.toml",     "checkpoint.bin",      "particles_final.csv",
                                      "domain.vtp",      "particles.pvd",       "particles_failed.vtp",
                                      "view.py"};
  const auto digits = [](const std::string& t, std::size_t min) {
    return t.size() >= min && std::all_of(t.begin(), t.end(), [](char c) { return c >= '0' && c <= '9'; });
  };
  const auto known = [&](const std::string& n) {
    for (const char* f : fixed)
      if (n == f) return true;
    // particles_NNNNN.vtp: a snapshot (five digits or more).
    const std::string pre = "particles_", post = ".vtp";
    return n.size() > pre.size() + post.size() && n.compare(0, pre.size(), pre) == 0 &&
           n.compare(n.size() - post.size(), post.size(), post) == 0 &&
           digits(n.substr(pre.size(), n.size() - pre.size() - post.size()), 5);
  };
  if (known(name)) return true;
  const std::size_t tmp = name.rfind(".tmp");
  return tmp != std::string::npos && tmp > 0 && digits(name.substr(tmp + 4), 1) && known(name.substr(0, tmp));
}

}  // namespace

OutputLock::~OutputLock() {
  if (fd_ < 0) return;
  ::unlink(path_.c_str());
  ::close(fd_);
}

std::string OutputLock::acquire(const fs::path& dir) {
  path_ = dir / ".otfp.lock";
  for (int attempt = 0; attempt < 5; ++attempt) {
    const int fd = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) return std::string("cannot write there: ") + std::strerror(errno);
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const int e = errno;
      ::close(fd);
      if (e == EWOULDBLOCK) return "in use by another otfp run (" + path_.string() + " is locked)";
      return std::string("cannot lock ") + path_.string() + ": " + std::strerror(e);
    }
    // The holder before us may have removed the file between our open and
    // our flock: then the lock is on a file nobody else sees; take it again.
    struct stat held {}, named {};
    if (::fstat(fd, &held) == 0 && ::stat(path_.c_str(), &named) == 0 && held.st_ino == named.st_ino &&
        held.st_dev == named.st_dev) {
      fd_ = fd;
      const std::string pid = std::to_string(::getpid()) + "\n";
      if (::ftruncate(fd_, 0) == 0 && ::write(fd_, pid.data(), pid.size()) < 0) {
        // The pid is only informative.
      }
      return "";
    }
    ::close(fd);
  }
  return "cannot lock " + path_.string() + ": it keeps being replaced";
}

std::string prepare_out_dir(const fs::path& dir, bool resume, bool overwrite, OutputLock& lock,
                            std::string_view overwrite_name) {
  const std::string flag(overwrite_name);
  std::error_code ec;
  const bool existed = fs::exists(dir, ec);
  if (ec && ec != std::errc::no_such_file_or_directory) return "cannot use it: " + ec.message();
  if (existed && !fs::is_directory(dir, ec)) return "exists and is not a directory";
  if (!existed) {
    fs::create_directories(dir, ec);
    if (ec) return "cannot create the directory: " + ec.message();
  }
  if (std::string why = lock.acquire(dir); !why.empty()) {
    if (!existed) fs::remove(dir, ec);  // the directory just made, still empty
    return why;
  }
  if (resume) return "";
  std::string earlier;
  for (const char* f : {"summary.json", "series.csv", "checkpoint.bin"})
    if (earlier.empty() && fs::exists(dir / f, ec)) earlier = f;
  if (earlier.empty()) return "";
  if (!overwrite)
    return "holds an earlier otfp run (" + earlier +
           "); pass " + flag + " to replace its files, or continue it with otfp run --resume " + dir.string();
  std::vector<fs::path> old_files;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec))
    if (is_run_output(e.path().filename().string()) && !e.is_directory()) old_files.push_back(e.path());
  if (ec) return flag + " cannot list the directory: " + ec.message();
  for (const fs::path& f : old_files)
    if (!fs::remove(f, ec) && ec) return flag + " cannot remove " + f.string() + ": " + ec.message();
  return "";
}

}  // namespace otfp::app
