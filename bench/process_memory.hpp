#pragma once
// The benchmarks' memory figures: fields of /proc/self/status.
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

namespace otfp::bench {

// A field of /proc/self/status in bytes (VmRSS, VmHWM); 0 where unavailable.
inline double status_bytes(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::size_t len = std::strlen(key);
  while (std::getline(in, line))
    if (line.compare(0, len, key) == 0 && line.size() > len && line[len] == ':')
      return 1024.0 * std::atof(line.c_str() + len + 1);
  return 0.0;
}

}  // namespace otfp::bench
