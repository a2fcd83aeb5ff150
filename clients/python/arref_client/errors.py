"""Typed errors: one class per server ErrorCode, each carrying the code the server sent."""

from ._proto import pb


class ArrefError(Exception):
    """Anything that went wrong talking to arref-server."""


class ConnectionClosed(ArrefError):
    """The server closed the connection (or it could not be opened)."""


class TlsError(ConnectionClosed):
    """The TLS handshake failed (e.g. the server does not speak TLS on that port)."""


class TlsVerificationFailed(TlsError):
    """The server's certificate did not verify: not signed by the trusted CA, not naming the host,
    expired or not yet valid; the message says which (OpenSSL's reason, e.g. "certificate has
    expired")."""


class Timeout(ArrefError):
    """No awaited reply within the timeout."""


class ServerError(ArrefError):
    """An Error message of the server, or a Result that is not a usable pose.

    code: the arref.v1.ErrorCode number; code_name its name (e.g. "ERROR_CODE_UNKNOWN_ROBOT").
    """

    def __init__(self, code, message, request_id=0, surface_id=0, fatal=False, result=None):
        self.code = int(code)
        self.code_name = pb.ErrorCode.Name(self.code) if self.code in pb.ErrorCode.values() else str(code)
        self.message = message
        self.request_id = request_id
        self.surface_id = surface_id
        self.fatal = fatal
        self.result = result  # the Result message, when the error is a Result's status
        super().__init__(f"{self.code_name}: {message}")


class InvalidArgument(ServerError): pass
class VersionMismatch(ServerError): pass
class Unauthenticated(ServerError): pass
class NotReady(ServerError): pass
class BadSurface(ServerError): pass
class UnknownSurface(ServerError): pass
class UnknownRobot(ServerError): pass
class UnknownRequest(ServerError): pass
class NoSeed(ServerError): pass
class NoScene(ServerError): pass
class Busy(ServerError): pass
class LimitExceeded(ServerError): pass
class MessageTooLarge(ServerError): pass
class MalformedMessage(ServerError): pass
class RegistrationFailed(ServerError): pass
class Cancelled(ServerError): pass
class ShuttingDown(ServerError): pass
class IdleTimeout(ServerError): pass
class InternalError(ServerError): pass
class HandshakeTimeout(ServerError): pass
class FrameTimeout(ServerError): pass
class NotTracking(ServerError): pass
class BadDepthFrame(ServerError): pass


_BY_CODE = {
    pb.ERROR_CODE_INVALID_ARGUMENT: InvalidArgument,
    pb.ERROR_CODE_VERSION_MISMATCH: VersionMismatch,
    pb.ERROR_CODE_UNAUTHENTICATED: Unauthenticated,
    pb.ERROR_CODE_NOT_READY: NotReady,
    pb.ERROR_CODE_BAD_SURFACE: BadSurface,
    pb.ERROR_CODE_UNKNOWN_SURFACE: UnknownSurface,
    pb.ERROR_CODE_UNKNOWN_ROBOT: UnknownRobot,
    pb.ERROR_CODE_UNKNOWN_REQUEST: UnknownRequest,
    pb.ERROR_CODE_NO_SEED: NoSeed,
    pb.ERROR_CODE_NO_SCENE: NoScene,
    pb.ERROR_CODE_BUSY: Busy,
    pb.ERROR_CODE_LIMIT_EXCEEDED: LimitExceeded,
    pb.ERROR_CODE_MESSAGE_TOO_LARGE: MessageTooLarge,
    pb.ERROR_CODE_MALFORMED_MESSAGE: MalformedMessage,
    pb.ERROR_CODE_REGISTRATION_FAILED: RegistrationFailed,
    pb.ERROR_CODE_CANCELLED: Cancelled,
    pb.ERROR_CODE_SHUTTING_DOWN: ShuttingDown,
    pb.ERROR_CODE_IDLE_TIMEOUT: IdleTimeout,
    pb.ERROR_CODE_INTERNAL: InternalError,
    pb.ERROR_CODE_HANDSHAKE_TIMEOUT: HandshakeTimeout,
    pb.ERROR_CODE_FRAME_TIMEOUT: FrameTimeout,
    pb.ERROR_CODE_NOT_TRACKING: NotTracking,
    pb.ERROR_CODE_BAD_DEPTH_FRAME: BadDepthFrame,
}


def error_from_message(error):
    """The typed exception of an arref.v1.Error message (codes this client does not know: ServerError)."""
    cls = _BY_CODE.get(error.code, ServerError)
    return cls(error.code, error.message, error.request_id, error.surface_id, error.fatal)


def error_from_result(result):
    """The exception of a Result whose status is FAILED or CANCELLED."""
    if result.status == pb.RESULT_STATUS_CANCELLED:
        code = result.error_code or pb.ERROR_CODE_CANCELLED
        return Cancelled(code, result.message, result.request_id, result=result)
    code = result.error_code or pb.ERROR_CODE_REGISTRATION_FAILED
    cls = _BY_CODE.get(code, RegistrationFailed)
    if not issubclass(cls, RegistrationFailed):  # keep `except RegistrationFailed` catching every FAILED result
        cls = RegistrationFailed
    return cls(code, result.message, result.request_id, result=result)
