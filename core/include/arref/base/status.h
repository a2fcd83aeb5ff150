// Status and Result: the error type of every fallible call in arref (LevelDB style).
#pragma once

#include <string>
#include <utility>
#include <variant>

namespace arref {

enum class StatusCode {
  kOk = 0,
  kInvalidArgument,   // the caller's input is malformed (bad mesh, unknown joint, ...)
  kNotFound,          // a file, robot or package that was named does not exist
  kIoError,           // a file exists but could not be read or parsed
  kFailedPrecondition,// valid input that cannot be processed (e.g. empty crop)
  kResourceExhausted, // a configured limit was hit
  kCancelled,
  kUnavailable,
  kInternal,
};

const char* StatusCodeName(StatusCode code);

class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  static Status Ok() { return {}; }
  static Status InvalidArgument(std::string m) { return {StatusCode::kInvalidArgument, std::move(m)}; }
  static Status NotFound(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
  static Status IoError(std::string m) { return {StatusCode::kIoError, std::move(m)}; }
  static Status FailedPrecondition(std::string m) { return {StatusCode::kFailedPrecondition, std::move(m)}; }
  static Status ResourceExhausted(std::string m) { return {StatusCode::kResourceExhausted, std::move(m)}; }
  static Status Cancelled(std::string m) { return {StatusCode::kCancelled, std::move(m)}; }
  static Status Internal(std::string m) { return {StatusCode::kInternal, std::move(m)}; }

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }
  // "INVALID_ARGUMENT: surface 3: vertex 7 is not finite"
  std::string ToString() const;
  // Prefixes context to the message, keeping the code: "loading kr5.urdf: ...".
  Status WithContext(const std::string& context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

// A value or the Status explaining why there is none.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::move(value)) {}                // NOLINT: implicit by design
  Result(Status status) : v_(std::move(status)) {}         // NOLINT: implicit by design

  bool ok() const { return std::holds_alternative<T>(v_); }
  const Status& status() const {
    static const Status kOkStatus;
    return ok() ? kOkStatus : std::get<Status>(v_);
  }
  T& value() & { return std::get<T>(v_); }
  const T& value() const& { return std::get<T>(v_); }
  T&& value() && { return std::get<T>(std::move(v_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

 private:
  std::variant<T, Status> v_;
};

}  // namespace arref

#define ARREF_RETURN_IF_ERROR(expr)            \
  do {                                         \
    ::arref::Status arref_status_ = (expr);    \
    if (!arref_status_.ok()) return arref_status_; \
  } while (0)

#define ARREF_STATUS_CONCAT_INNER_(a, b) a##b
#define ARREF_STATUS_CONCAT_(a, b) ARREF_STATUS_CONCAT_INNER_(a, b)

// ARREF_ASSIGN_OR_RETURN(lhs, expr): evaluates expr (a Result<T>); on error returns its Status
// from the calling function, else moves the value into lhs, which may declare a variable:
//   ARREF_ASSIGN_OR_RETURN(auto mesh, robot.PosedMesh(joints));
#define ARREF_ASSIGN_OR_RETURN(lhs, expr) \
  ARREF_ASSIGN_OR_RETURN_IMPL_(ARREF_STATUS_CONCAT_(arref_result_, __LINE__), lhs, expr)
#define ARREF_ASSIGN_OR_RETURN_IMPL_(result, lhs, expr) \
  auto result = (expr);                                 \
  if (!result.ok()) return result.status();             \
  lhs = std::move(result).value()
