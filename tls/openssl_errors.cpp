#include "openssl_errors.h"

#include <openssl/err.h>
#include <openssl/x509.h>

#include <cerrno>
#include <cstring>

namespace arref::tls {

std::string OpenSslErrors() {
  std::string out;
  while (const unsigned long e = ERR_get_error()) {
    char text[256];
    ERR_error_string_n(e, text, sizeof text);
    out += (out.empty() ? "" : "; ") + std::string(text);
  }
  return out;
}

std::string OpenSslErrorsOrErrno() {
  const int system_error = errno;  // before anything below can change it
  const std::string out = OpenSslErrors();
  return out.empty() ? std::string(std::strerror(system_error)) : out;
}

std::string CertificateSubject(const X509* certificate) {
  char name[256] = "?";
  X509_NAME_oneline(X509_get_subject_name(certificate), name, sizeof name);
  return name;
}

CertificateDates DatesOf(const X509* certificate) {
  if (X509_cmp_current_time(X509_get0_notAfter(certificate)) < 0) return CertificateDates::kExpired;
  if (X509_cmp_current_time(X509_get0_notBefore(certificate)) > 0) return CertificateDates::kNotYetValid;
  return CertificateDates::kValid;
}

}  // namespace arref::tls
