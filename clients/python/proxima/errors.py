"""ProximaError: every failed call, with the gRPC status code."""
from typing import Optional

import grpc


class ProximaError(Exception):
    """A failed call. `code` is the grpc.StatusCode (`code_name` its name, "NOT_FOUND"), and
    `details` the daemon's message (also `message`). Raised for every RPC that fails, and for
    client-side failures that have a status of their own (an unreachable daemon is UNAVAILABLE,
    an unreadable token file NOT_FOUND or FAILED_PRECONDITION)."""

    def __init__(self, code: grpc.StatusCode, details: str):
        self.code: grpc.StatusCode = code
        self.details: str = details
        super().__init__(f"{self.code_name}: {details}")

    @property
    def code_name(self) -> str:
        """The status code's name: "INVALID_ARGUMENT", "NOT_FOUND", ..."""
        return self.code.name

    @property
    def message(self) -> str:
        """The daemon's message (the same as `details`)."""
        return self.details

    @staticmethod
    def from_rpc(error: grpc.RpcError) -> "ProximaError":
        """The ProximaError of a grpc.RpcError (UNKNOWN when it carries no status)."""
        code: Optional[grpc.StatusCode] = error.code() if hasattr(error, "code") else None
        details = error.details() if hasattr(error, "details") else str(error)
        return ProximaError(code if code is not None else grpc.StatusCode.UNKNOWN, details or "")
