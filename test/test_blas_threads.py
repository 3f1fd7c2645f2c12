"""numpy's BLAS runs one thread in processes that import planar_vo first (planar_vo/__init__.py).

OpenBLAS starts its worker threads when numpy loads it; the process's threads are counted in
/proc (Linux). No timing here: what one thread saves is measured in docs/speed.md.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COUNT = "import os; print(len(os.listdir('/proc/self/task')), os.environ['OPENBLAS_NUM_THREADS'])"


def _threads(imports: str, **env: str) -> tuple[int, str]:
    clean = {k: v for k, v in os.environ.items() if k not in ('OPENBLAS_NUM_THREADS',
                                                               'OMP_NUM_THREADS')}
    clean['PYTHONPATH'] = str(ROOT)
    out = subprocess.run([sys.executable, '-c', f'{imports}; {COUNT}'], env=clean | env,
                         capture_output=True, text=True, check=True, timeout=60).stdout.split()
    return int(out[0]), out[1]


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason='one core: BLAS starts no threads anyway')
def test_blas_runs_one_thread_where_planar_vo_is_imported_first():
    assert _threads('import planar_vo, numpy') == (1, '1')
    # The control: numpy loaded first has started its threads before the package could say.
    threads, _ = _threads('import numpy, planar_vo')
    assert threads > 1


def test_a_thread_count_the_user_set_is_kept():
    assert _threads('import planar_vo, numpy', OPENBLAS_NUM_THREADS='2')[1] == '2'
