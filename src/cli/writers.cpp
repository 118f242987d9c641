#include "otfp_app/writers.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <fmt/format.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace otfp::app {

namespace {

[[noreturn]] void io_error(const std::string& what, const std::filesystem::path& path) {
  throw std::runtime_error(what + " '" + path.string() + "': " + std::strerror(errno));
}

void write_all(int fd, std::string_view data, const std::filesystem::path& path) {
  while (!data.empty()) {
    const ssize_t n = ::write(fd, data.data(), data.size());
    if (n < 0) {
      if (errno == EINTR) continue;
      io_error("cannot write", path);
    }
    data.remove_prefix(static_cast<std::size_t>(n));
  }
}

// What kill_time_cleanup() works on. The handler may run on any thread while
// the main thread goes on, so every buffer it reads is published through an
// atomic pointer after it is complete and never changed while published
// (the summary alternates between two slots).
struct KillTimeState {
  char current_tmp[4096] = {};                  // the file write_file_atomic is writing
  std::atomic<bool> writing{false};
  std::vector<std::string> paths;               // removed at kill time
  std::atomic<const std::vector<std::string>*> published_paths{nullptr};
  std::string summary_path, summary_tmp;
  std::string summary[2];
  std::atomic<int> summary_slot{-1};            // the slot that is complete, -1: none
};
// At namespace scope, not a function's static: the handler must not be the
// first to touch it (a guarded initialisation is not async-signal-safe).
KillTimeState g_kill_state;
KillTimeState& kill_state() { return g_kill_state; }

// Restores a write_file_atomic's "not writing" on every way out.
struct WritingMark {
  explicit WritingMark(const std::filesystem::path& tmp) {
    KillTimeState& k = kill_state();
    const std::string& t = tmp.native();
    if (t.size() < sizeof k.current_tmp) {
      std::memcpy(k.current_tmp, t.c_str(), t.size() + 1);
      k.writing.store(true);
    }
  }
  ~WritingMark() { kill_state().writing.store(false); }
  WritingMark(const WritingMark&) = delete;
  WritingMark& operator=(const WritingMark&) = delete;
};

}  // namespace

void set_kill_time_paths(std::vector<std::filesystem::path> paths) {
  KillTimeState& k = kill_state();
  k.published_paths.store(nullptr);
  k.paths.clear();
  for (const auto& p : paths) k.paths.push_back(p.string());
  k.published_paths.store(&k.paths);
}

void set_kill_time_summary(const std::filesystem::path& path, std::string content) {
  KillTimeState& k = kill_state();
  if (k.summary_slot.load() < 0 || k.summary_path != path.string()) {
    k.summary_slot.store(-1);
    k.summary_path = path.string();
    k.summary_tmp = k.summary_path + fmt::format(".tmp{}", ::getpid());
  }
  const int next = k.summary_slot.load() == 0 ? 1 : 0;
  k.summary[next] = std::move(content);
  k.summary_slot.store(next);
}

void clear_kill_time_state() {
  KillTimeState& k = kill_state();
  k.published_paths.store(nullptr);
  k.summary_slot.store(-1);
}

void kill_time_cleanup() noexcept {
  KillTimeState& k = kill_state();
  if (k.writing.load()) ::unlink(k.current_tmp);
  if (const std::vector<std::string>* paths = k.published_paths.load())
    for (const std::string& p : *paths) ::unlink(p.c_str());
  const int slot = k.summary_slot.load();
  if (slot < 0) return;
  const std::string& text = k.summary[slot];
  const int fd = ::open(k.summary_tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return;
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  if (done != text.size() || ::rename(k.summary_tmp.c_str(), k.summary_path.c_str()) != 0)
    ::unlink(k.summary_tmp.c_str());
}

void write_file_atomic(const std::filesystem::path& path, std::string_view content) {
  std::filesystem::path tmp = path;
  tmp += fmt::format(".tmp{}", ::getpid());
  const WritingMark mark(tmp);  // a run killed now removes tmp (kill_time_cleanup)
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) io_error("cannot create", tmp);
  try {
    write_all(fd, content, tmp);
  } catch (...) {
    ::close(fd);
    ::unlink(tmp.c_str());
    throw;
  }
  if (::close(fd) != 0) {
    const int e = errno;
    ::unlink(tmp.c_str());
    errno = e;
    io_error("cannot close", tmp);
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const int e = errno;
    ::unlink(tmp.c_str());
    errno = e;
    io_error("cannot rename onto", path);
  }
}

AppendFile::AppendFile(const std::filesystem::path& path, std::string_view header) : path_(path) {
  write_file_atomic(path, header);
  fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (fd_ < 0) io_error("cannot open", path);
  const off_t end = ::lseek(fd_, 0, SEEK_END);
  if (end < 0) io_error("cannot seek in", path);
  size_ = static_cast<std::uint64_t>(end);
}

AppendFile::~AppendFile() {
  if (fd_ >= 0) ::close(fd_);
}

AppendFile::AppendFile(AppendFile&& other) noexcept
    : fd_(other.fd_), path_(std::move(other.path_)), size_(other.size_) {
  other.fd_ = -1;
}

AppendFile& AppendFile::operator=(AppendFile&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = other.fd_;
    path_ = std::move(other.path_);
    size_ = other.size_;
    other.fd_ = -1;
  }
  return *this;
}

void AppendFile::append(std::string_view lines) {
  if (fd_ < 0) throw std::runtime_error("AppendFile: not open");
  try {
    write_all(fd_, lines, path_);
  } catch (const std::exception& e) {
    // Whatever part of the lines reached the file goes again.
    const bool cut = ::ftruncate(fd_, static_cast<off_t>(size_)) == 0;
    throw std::runtime_error(std::string(e.what()) +
                             (cut ? " (cut back to its last complete row)" : " (and it could not be cut back: the last row may be partial)"));
  }
  size_ += lines.size();
}

void AppendFile::truncate(std::uint64_t size) {
  if (fd_ < 0 || size >= size_) return;
  if (::ftruncate(fd_, static_cast<off_t>(size)) != 0) io_error("cannot cut back", path_);
  size_ = size;
}

}  // namespace otfp::app
