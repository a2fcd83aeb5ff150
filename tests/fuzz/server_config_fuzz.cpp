// libFuzzer target: the server's YAML config loader (server/server_config) on arbitrary text.
// Every input must end in a config or a Status, never an exception, crash or leak; a config
// that parses is validated too, as the server does before serving.
#include <cstddef>
#include <cstdint>
#include <string>

#include "server_config.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  auto config = arref::server::ParseServerConfig(text, "/nonexistent/arref-fuzz");
  if (config.ok()) (void)arref::server::ValidateServerConfig(*config);
  return 0;
}
