"""Errors SEAL raises on purpose. Each message names what was wrong and what is valid."""


class SealError(Exception):
    """Base class of every error SEAL raises deliberately."""


class InvalidInput(SealError, ValueError):
    """A caller passed something SEAL cannot use (unknown name, bad shape, out of range)."""


class SimulationError(SealError, RuntimeError):
    """The physics became unstable (NaN/Inf state). Episodes end as `sim_error`."""


class PolicyError(SealError, RuntimeError):
    """A policy answered with something no world can execute (non-finite actions): broken weights or
    inputs. It ends the episode as an error, never as a silent failure."""


class WorkerCrashed(SealError, RuntimeError):
    """A pool worker process died while it held the env that this result belongs to."""


class VerifierUnavailable(SealError, RuntimeError):
    """The verifier cannot give any verdict: a wrong key, model name or URL, a server that is not
    there. Retrying will not help and every later verdict would be missing too, so the run stops
    with this reason instead of carrying on unverified. (A transient failure that outlasts its
    retries is not this: it becomes an unknown verdict with ``extra["error"]``, counted per trial.)"""
