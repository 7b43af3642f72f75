"""A real writer process for the crash and lock tests (run as a script, not collected).

usage: python store_writer_proc.py STORE SEED N_FRAMES [HOLD_SECONDS]

Writes stage /hsc with N_FRAMES deterministic frames (content derived from SEED) through
the store's streaming frame writer (``StageWriter.write_frames``: worker threads, direct
chunk writes; the path `vfcli ingest-hsc` takes), 16 frames per batch, printing "writing"
once the transaction has started. With HOLD_SECONDS it sleeps inside the transaction (to
hold the lock).
"""
import sys
import time

import numpy as np

from vfcli.store import Store


def hold(seconds: float) -> None:
    """Sleep ``seconds`` in 50 ms slices: a signal that lands between Python's last look at its signal flag and a
    sleep's system call sets the flag and wakes nothing, and one long sleep would keep it waiting to its end (the same
    lost wakeup as a Ctrl-C test's on CI, session 69); a slice ends within 50 ms."""
    for _ in range(round(seconds / 0.05)):
        time.sleep(0.05)


def frames_for(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 4096, size=(n, 128, 128), dtype=np.uint16)


def main() -> None:
    path, seed, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    seconds = float(sys.argv[4]) if len(sys.argv) > 4 else 0.0
    frames = frames_for(seed, n)
    with Store(path).write(f"writer {seed}") as w:
        print("writing", flush=True)
        hold(seconds)
        with w.stage("hsc", config_json=f'{{"seed": {seed}}}') as s:
            s.write_frames("frames", frames.shape, np.uint16, (frames[a:a + 16] for a in range(0, n, 16)))
            s.put("frame_time", np.arange(n) / 10000.0)
            s.set_attrs(seed=seed)


if __name__ == "__main__":
    main()
