"""core.record.sample_log: rows round-trip through disk; memory held is one block, whatever the
length.
"""

import numpy as np
import pytest

from curve_formation.core.record.sample_log import SampleLog


FIELDS = {'t': ((), float), 'poses': ((3, 3), float), 'curve_id': ((), np.int64),
          'unseen': ((3,), bool)}


def rows(count):
    for k in range(count):
        yield {'t': 0.05 * k, 'poses': np.full((3, 3), float(k)), 'curve_id': k // 100,
               'unseen': np.array([k % 2 == 0, False, k % 3 == 0])}


@pytest.mark.parametrize('count', [0, 1, 63, 64, 65, 1000])
def test_every_row_comes_back_in_order_across_blocks(count):
    with SampleLog(FIELDS, block_rows=64) as log:
        for row in rows(count):
            log.append(**row)
        data = log.arrays()
        assert len(log) == count
        assert {k: v.shape for k, v in data.items()} == {
            't': (count,), 'poses': (count, 3, 3), 'curve_id': (count,), 'unseen': (count, 3)}
        expected = list(rows(count))
        np.testing.assert_array_equal(data['t'], [r['t'] for r in expected])
        np.testing.assert_array_equal(data['poses'][:, 1, 2], np.arange(count))
        np.testing.assert_array_equal(data['curve_id'], [r['curve_id'] for r in expected])
        np.testing.assert_array_equal(data['unseen'][:, 0], np.arange(count) % 2 == 0)
        assert data['curve_id'].dtype == np.int64 and data['unseen'].dtype == bool


def test_memory_held_is_one_block_and_the_rest_is_on_disk():
    log = SampleLog(FIELDS, block_rows=64)
    for row in rows(64 * 50 + 10):
        log.append(**row)
    assert log._held == 10
    assert all(len(block) == 64 for block in log._block.values())
    assert (log.directory / 'poses.bin').stat().st_size == 64 * 50 * 9 * 8
    assert log.last('t') == pytest.approx(0.05 * (64 * 50 + 9))
    directory = log.directory
    log.close()
    assert not directory.exists()   # a temporary directory goes with the log


def test_a_given_directory_is_kept_and_a_row_with_wrong_fields_is_refused(tmp_path):
    log = SampleLog(FIELDS, directory=tmp_path / 'samples', block_rows=4)
    with pytest.raises(KeyError, match='expected'):
        log.append(t=0.0)
    for row in rows(9):
        log.append(**row)
    log.flush()
    log.close()
    assert (tmp_path / 'samples' / 't.bin').stat().st_size == 9 * 8
