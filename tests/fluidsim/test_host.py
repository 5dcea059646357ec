"""fluidsim.host: one answer to "how much memory may this process still allocate", shared by the probe run's memory
check (nbv.physics.memory) and the readers' decode budget (recon.inflate); an address-space limit (ulimit -v) lowers
it."""

import resource

from fluidsim import host


def test_an_address_space_limit_lowers_the_available_memory(monkeypatch):
    from nbv.physics import PhysicsConfig, memory
    from recon import inflate

    free = host.available_memory_bytes()
    assert free > 0
    limit = host.virtual_size_bytes() + 2**20  # 1 MiB above the process's current size
    monkeypatch.setattr(resource, "getrlimit", lambda which: (limit, resource.RLIM_INFINITY))
    assert host.available_memory_bytes() <= 2**20
    assert memory.memory_limit_bytes(PhysicsConfig()) <= 2**20  # the probe run's check reads the same owner
    assert inflate.available_memory_bytes is host.available_memory_bytes
