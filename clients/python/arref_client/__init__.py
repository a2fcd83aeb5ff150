"""Python client of arref-server: connect, upload a mesh, seed, register, subscribe, track, replay.

    from arref_client import Client
    with Client("127.0.0.1", 7311) as c:
        c.upload_mesh("scene.ply", frame="ros")
        result = c.register("kr5", seed=(1.0, 0.2, 0.0, 0, 0, 0, 1), frame="ros")
        print(result.status, result.pose, result.matrix)
        # With no seed (here or in the session) the server searches the whole map:
        for instance in c.register("kr5").candidates:
            print(instance.status, instance.pose)
"""

from .client import Candidate, Client, RegistrationResult, RobotInfo, frame_convention, tls_context, DEFAULT_PORT, PROTOCOL_VERSION
from .errors import ArrefError, ConnectionClosed, Timeout, ServerError, RegistrationFailed, Cancelled
from .mesh import Mesh, load_mesh, split_into_surfaces
from .tracking import ClockOffsetEstimator, TrackingUpdate, TrackOutcome, TrackTruth
from ._proto import pb

__all__ = ["Candidate", "Client", "RegistrationResult", "RobotInfo", "frame_convention", "tls_context", "DEFAULT_PORT",
           "PROTOCOL_VERSION",
           "ArrefError", "ConnectionClosed", "Timeout", "ServerError", "RegistrationFailed", "Cancelled",
           "Mesh", "load_mesh", "split_into_surfaces", "pb", "ClockOffsetEstimator", "TrackingUpdate", "TrackOutcome",
           "TrackTruth"]
__version__ = "0.1.0"
