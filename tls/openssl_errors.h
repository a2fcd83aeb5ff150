// OpenSSL's errors and certificates as text, for the messages of the server's and the clients'
// TLS code.
#pragma once

#include <openssl/types.h>

#include <string>

namespace arref::tls {

// OpenSSL's queued errors as one line ("a; b"), or "" when none; empties the queue.
std::string OpenSslErrors();

// The same, but when OpenSSL queued nothing (a failed system call under it), the system's
// error (errno) as text.
std::string OpenSslErrorsOrErrno();

// A certificate's subject as one line ("/CN=localhost"), "?" when it has none.
std::string CertificateSubject(const X509* certificate);

// Where this machine's clock falls in a certificate's validity.
enum class CertificateDates { kValid, kExpired, kNotYetValid };
CertificateDates DatesOf(const X509* certificate);

}  // namespace arref::tls
