"""Memory checks against what the process may really have: its address-space limit and its
cgroup's limit as well as the machine's free memory."""

import subprocess
import sys
import textwrap

from piest_jax._cli import memory


def test_an_address_space_limit_is_what_the_check_reads():
    # A real limit in a child process: the room it leaves is the available memory, and a request
    # beyond it is refused in one line naming the limit, before any work.
    code = textwrap.dedent(
        """
        import resource, sys
        import jax, matplotlib
        from piest_jax._cli import main, memory
        used = memory._status_bytes("VmSize")
        resource.setrlimit(resource.RLIMIT_AS, (used + 1024 * 2**20, resource.RLIM_INFINITY))
        room = memory.available_bytes()
        assert 900 * 2**20 < room <= 1024 * 2**20, room
        assert "address-space limit" in memory._available()[1]
        sys.exit(main(["simulate", "--duration", "1000", "--plays", "49", "--r-max", "5", "--out", sys.argv[1]]))
        """
    )
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        run = subprocess.run([sys.executable, "-c", code, d + "/o"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 2, run.stderr
    err = run.stderr.strip()
    assert len(err.splitlines()) == 1, err
    assert "1000001 samples x 49 plays needs about" in err
    assert "left under this process's address-space limit (ulimit -v); use fewer plays or samples" in err


def test_a_cgroup_limit_is_read(tmp_path):
    (tmp_path / "memory.max").write_text("1073741824\n")
    (tmp_path / "memory.current").write_text("268435456\n")
    assert memory._cgroup_room(str(tmp_path)) == 768 * 2**20
    (tmp_path / "memory.max").write_text("max\n")  # no limit
    assert memory._cgroup_room(str(tmp_path)) is None
    v1 = tmp_path / "v1"
    (v1 / "memory").mkdir(parents=True)
    (v1 / "memory" / "memory.limit_in_bytes").write_text(str(2**63 - 4096))  # v1's "no limit"
    assert memory._cgroup_room(str(v1)) is None
    (v1 / "memory" / "memory.limit_in_bytes").write_text(str(2**30))
    (v1 / "memory" / "memory.usage_in_bytes").write_text(str(2**29))
    assert memory._cgroup_room(str(v1)) == 2**29
