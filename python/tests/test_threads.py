"""Objects shared between threads: every bound object that releases the GIL
serialises its methods (a per-object lock, taken with the GIL released), so
that two threads stepping one Simulation or sharing one stepper take turns
and give what the same calls give one after another.

The crash scenarios run in a subprocess, several times: before the lock they
ended in SIGSEGV, which would take pytest down with them."""
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest

import otfp

PRELUDE = textwrap.dedent("""
    import threading
    import numpy as np
    import otfp

    def small_simulation():
        domain = otfp.make_ball(3, [0, 0, 0], 1.0)
        n = 120
        opts = otfp.SimulationOptions(particle_mass=1.0 / n, width_s=0.12, barrier_stiffness=400.0,
                                      projection=dict(layer_b=0.15), seed=11)
        sim = otfp.Simulation(domain, [otfp.BoundaryData(patch=0, kind="dirichlet", value=1.0)], opts)
        fill = otfp.fill_particles(domain, otfp.FillOptions(count=n // 4, width_s=0.12, mass=1.0 / n), seed=5)
        sim.start(fill)
        return sim

    def in_threads(*targets):
        errors = []
        def wrap(f):
            def g():
                try:
                    f()
                except BaseException as e:  # reported by the main thread
                    errors.append(e)
            return g
        threads = [threading.Thread(target=wrap(f)) for f in targets]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            raise errors[0]
""")


def run_script(body, tries):
    """Runs PRELUDE + body `tries` times in fresh interpreters; returns their outputs."""
    outputs = []
    for _ in range(tries):
        r = subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(body)], capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, f"exit {r.returncode} (negative: killed by a signal): {r.stderr[-2000:]}"
        outputs.append(r.stdout)
    return outputs


def test_two_threads_advancing_one_simulation_take_turns():
    # 2 x 4 steps of dt from two threads are the 8 steps of one thread, bit for bit.
    outputs = run_script("""
        sim = small_simulation()
        def steps():
            for _ in range(4):
                sim.advance(0.0025)
        in_threads(steps, steps)
        serial = small_simulation()
        for _ in range(8):
            serial.advance(0.0025)
        assert sim.step_count == 8, sim.step_count
        assert otfp.particles_csv(sim.particles) == otfp.particles_csv(serial.particles)
        print("ok")
    """, tries=4)
    assert outputs == ["ok\n"] * 4


def test_reading_a_simulation_while_another_thread_steps_it():
    run_script("""
        sim = small_simulation()
        done = threading.Event()
        def steps():
            sim.run_until(0.02, 0.0025)
            done.set()
        def reads():
            while not done.is_set():
                ps = sim.particles
                ms, region = sim.measure([0, 0, 0])
                assert len(region) == ms.n_particles
                assert np.isfinite(ps.positions).all()
                assert sim.ledger.expected_particles() >= 0 and sim.time <= 0.02
        in_threads(steps, reads)
        assert sim.step_count == 8
    """, tries=3)


def test_threads_sharing_one_implicit_stepper_take_turns():
    # Each thread steps its own particles with the shared stepper; with Euler
    # steps and no predictor a step depends only on its particles, so every
    # result equals the one a stepper of its own gives.
    outputs = run_script("""
        domain = otfp.make_box(3, [-1, -1, -1], [1, 1, 1])
        stepper = otfp.ImplicitStepper(domain, otfp.ImplicitOptions(kappa=1.0), barrier_stiffness=100.0)
        def particles(seed):
            rng = np.random.default_rng(seed)
            n = 80
            return otfp.ParticleSet(3, rng.uniform(-0.5, 0.5, (n, 3)), np.full(n, 0.2), np.full(n, 1.0 / n))
        sets = [particles(k) for k in range(2)]
        def steps(ps):
            def run():
                for _ in range(3):
                    assert stepper.step(ps, 0.002).accepted
            return run
        in_threads(steps(sets[0]), steps(sets[1]))
        for k in range(2):
            own = otfp.ImplicitStepper(domain, otfp.ImplicitOptions(kappa=1.0), barrier_stiffness=100.0)
            ref = particles(k)
            for _ in range(3):
                own.step(ref, 0.002)
            assert otfp.particles_csv(sets[k]) == otfp.particles_csv(ref), k
        print("ok")
    """, tries=4)
    assert outputs == ["ok\n"] * 4


def test_threads_sharing_an_explicit_stepper_and_a_functional():
    run_script("""
        stepper = otfp.ExplicitStepper(options=otfp.ExplicitOptions(kappa=1.0), dim=2)
        f = otfp.Functional(options=otfp.FunctionalOptions(dt=0.01), dim=2)
        rng = np.random.default_rng(3)
        x = rng.uniform(-1, 1, (60, 2))
        f.set_reference(x, np.full(60, 0.3), np.full(60, 1.0 / 60))
        value = f.evaluate(x, np.full(60, 0.3))["value"]
        sets = [otfp.ParticleSet(2, x, np.full(60, 0.3), np.full(60, 1.0 / 60)) for _ in range(2)]
        def work(ps):
            def run():
                for _ in range(20):
                    stepper.step(ps, 1e-4)
                    f.set_reference(x, np.full(60, 0.3), np.full(60, 1.0 / 60))
                    assert f.evaluate(x, np.full(60, 0.3))["value"] == value
            return run
        in_threads(work(sets[0]), work(sets[1]))
        assert otfp.particles_csv(sets[0]) == otfp.particles_csv(sets[1])
    """, tries=3)


def test_the_observer_may_read_its_simulation_and_other_threads_wait():
    sim_holder = {}
    seen = []

    def observe(s, step):
        seen.append((s.time, s.step_count, len(s.particles)))  # the lock is this thread's: no deadlock

    def steps():
        sim_holder["sim"].run_until(0.01, 0.0025, observe)

    domain = otfp.make_ball(3, [0, 0, 0], 1.0)
    n = 120
    opts = otfp.SimulationOptions(particle_mass=1.0 / n, width_s=0.12, barrier_stiffness=400.0,
                                  projection=dict(layer_b=0.15), seed=11)
    sim = otfp.Simulation(domain, [otfp.BoundaryData(patch=0, kind="dirichlet", value=1.0)], opts)
    sim.start(otfp.fill_particles(domain, otfp.FillOptions(count=30, width_s=0.12, mass=1.0 / n), seed=5))
    sim_holder["sim"] = sim
    t = threading.Thread(target=steps)
    t.start()
    times = []
    while t.is_alive():
        times.append(sim.time)  # waits for the step in progress: never a half-taken step
    t.join()
    assert [k for _, k, _ in seen] == [1, 2, 3, 4]
    assert all(tt in (0.0, 0.0025, 0.005, 0.0075, 0.01) for tt in times)
