# Types of the compiled kernels in _walk.pyx (the extension has no annotations mypy can read).
import numpy as np

class WalkModel:
    def __init__(
        self,
        Pr: np.ndarray,
        Pi: np.ndarray,
        Qr: np.ndarray,
        nQi: np.ndarray,
        Ar: np.ndarray,
        Ai: np.ndarray,
        R: int,
        lane_ch: np.ndarray,
        lane_rec: np.ndarray,
        thr: float,
        thr2: float,
        rv: float,
        stable: bool,
    ) -> None: ...

def walk_lanes(
    model: WalkModel,
    lanes: np.ndarray,
    wr: np.ndarray,
    wi: np.ndarray,
    pend: np.ndarray,
    start: int,
    end: int,
    rows: np.ndarray,
    vals: np.ndarray,
    stop_first: bool,
    spikes: np.ndarray,
    trajectory: np.ndarray | None = None,
    spiked: np.ndarray | None = None,
) -> tuple[int, int, bool]: ...
def score(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[int, int, float, float, float]: ...
def score_many(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...
def score_matched(
    vals: np.ndarray, mat: np.ndarray, rank: np.ndarray
) -> tuple[int, int, float, float, float]: ...
def timings(
    chans: np.ndarray, omegas: np.ndarray, start: float, pulses: int, tau: float, search: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
def read_rows(
    rows: np.ndarray, vals: np.ndarray, idx: np.ndarray, chans: np.ndarray
) -> np.ndarray: ...
