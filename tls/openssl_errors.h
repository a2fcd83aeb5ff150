// OpenSSL's error queue as text, for the messages of the server's and the clients' TLS code.
#pragma once

#include <string>

namespace arref::tls {

// OpenSSL's queued errors as one line ("a; b"), or "" when none; empties the queue.
std::string OpenSslErrors();

// The same, but when OpenSSL queued nothing (a failed system call under it), the system's
// error (errno) as text.
std::string OpenSslErrorsOrErrno();

}  // namespace arref::tls
