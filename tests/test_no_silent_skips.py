"""The no-silent-skips rule of tests/conftest.py, run on a throw-away suite."""

from pathlib import Path

import pytest

pytest_plugins = ['pytester']
CONFTEST = (Path(__file__).parent / 'conftest.py').read_text()


@pytest.fixture
def suite(pytester):
    pytester.makeconftest(CONFTEST)
    pytester.makepyfile(
        test_a="""
        import pytest
        def test_passes():
            assert True
        def test_skips():
            pytest.skip('no reason good enough')
    """,
        test_b="""
        import pytest
        pytest.skip('whole module', allow_module_level=True)
    """,
    )
    return pytester


@pytest.mark.parametrize('flag', ['CI', 'KNODE_NO_SKIPS'])
def test_in_ci_a_skip_fails_the_run_and_is_listed(suite, monkeypatch, flag):
    monkeypatch.delenv('CI', raising=False)
    monkeypatch.setenv(flag, 'true')
    result = suite.runpytest('-p', 'no:cacheprovider')
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines(
        [
            '*no-skip rule on (CI): 2 skipped; allow-list: empty*',
            '*test_b.py: Skipped: whole module *NOT ALLOWED in CI*',  # at collection
            '*test_a.py::test_skips: Skipped: no reason good enough *NOT ALLOWED in CI*',
        ]
    )


def test_outside_ci_skips_are_listed_but_do_not_fail(suite, monkeypatch):
    monkeypatch.delenv('CI', raising=False)
    monkeypatch.delenv('KNODE_NO_SKIPS', raising=False)
    result = suite.runpytest('-p', 'no:cacheprovider')
    assert result.ret == pytest.ExitCode.OK
    result.stdout.fnmatch_lines(
        ['*test_a.py::test_skips: Skipped: no reason good enough *not allowed in CI*']
    )


def test_an_allow_listed_skip_passes_in_ci(pytester, monkeypatch):
    pytester.makeconftest(
        CONFTEST.replace('SKIP_ALLOW_LIST = {}', "SKIP_ALLOW_LIST = {'test_a.py::test_skips': 'demo'}")
    )
    pytester.makepyfile(
        test_a="""
        import pytest
        def test_skips():
            pytest.skip('fine here')
    """
    )
    monkeypatch.setenv('CI', 'true')
    result = pytester.runpytest('-p', 'no:cacheprovider')
    assert result.ret == pytest.ExitCode.OK
    result.stdout.fnmatch_lines(['*test_a.py::test_skips: Skipped: fine here *allowed: demo*'])
