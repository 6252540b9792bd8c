"""Fitting coefficient values to images (``sparse-brdf fit-images``, ``fit_images``):
the fit moves a perturbed encoding towards the references, keeps the support, resumes
from its checkpoint, and refuses bad input in one line (exit 2, no output)."""

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from test_reliability import run

from sparse_brdf import encode, load_brdf
from sparse_brdf.coding.fileformat import load_sbrdf, save_sbrdf
from sparse_brdf.errors import UsageError
from sparse_brdf.evaluation.images import write_exr
from sparse_brdf.evaluation.render import SHARED_PATHS
from sparse_brdf.evaluation.render import render_scene as _render_scene
from sparse_brdf.evaluation.scenes import find_scene
from sparse_brdf.fitting.fit_images import fit_images, views_for
from sparse_brdf.metrics import render_snr
from sparse_brdf.paths import DEMO_MATERIALS_DIR, PAPER_ENSEMBLE_ID

RES, SPP, ROTS = 16, 4, (0, 180)
MATERIAL = DEMO_MATERIALS_DIR / "silver-paint.h5"


def render_scene(*args, **kwargs):
    """Renders as the fit's own: cosine sampling, so a seed gives every material the same
    sample paths."""
    return _render_scene(*args, sampling=SHARED_PATHS, **kwargs)


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    """References of a measured material at two map rotations, its encoding, and that
    encoding with 30 % multiplicative noise on every value."""
    work = tmp_path_factory.mktemp("fit")
    scene = find_scene("sphere.xml")
    refs = {r: render_scene(scene, {"material": str(MATERIAL)}, spp=SPP, seed=0, res=RES,
                            params={"envrot": r}) for r in ROTS}
    paths = [write_exr(work / f"ref{r}.exr", refs[r]) for r in ROTS]
    # on the ensemble of the paper's transforms, whose values 30 % noise perturbs mildly
    # (the relative transforms' values are larger: the same noise is a harsher start)
    model = encode(load_brdf(MATERIAL), PAPER_ENSEMBLE_ID, n_coeffs=64)
    rng = np.random.default_rng(3)
    noisy = dataclasses.replace(model, values=[
        (v * (1 + 0.3 * rng.standard_normal(v.shape))).astype(np.float32)
        for v in model.values])
    start = save_sbrdf(work / "start.sbrdf", noisy)
    return {"work": work, "scene": scene, "refs": refs, "paths": paths, "start": start}


def _snr(case, path: Path) -> float:
    """Mean whole-image SNR of ``path``'s renders against the references (dB)."""
    return float(np.mean([render_snr(case["refs"][r], render_scene(
        case["scene"], {"material": str(path)}, spp=SPP, seed=0, res=RES,
        params={"envrot": r})) for r in ROTS]))


@pytest.mark.render
def test_fit_images_command_moves_towards_the_references(capsys, case):
    out = case["work"] / "fitted.sbrdf"
    views = [f"{p}:envrot={r}" for p, r in zip(case["paths"], ROTS, strict=True)]
    code, stdout, err = run(capsys, "fit-images", "sphere.xml", *sum([["--view", v]
                            for v in views], []), "--start", case["start"], "-o", out,
                            "--iterations", 12, "--lr", 0.05, "--spp", SPP)
    assert code == 0, err
    assert "wrote" in stdout and "12 iterations" in stdout
    start, fitted = load_sbrdf(case["start"]), load_sbrdf(out)
    # the support is kept: same dictionaries, same atoms (a file orders its terms by
    # size, so compare them as sets); only the values move
    assert np.array_equal(fitted.dict_index, start.dict_index)
    for a, b in zip(fitted.locations, start.locations, strict=True):
        assert np.array_equal(np.sort(a), np.sort(b))
    assert not all(np.array_equal(np.sort(a), np.sort(b))
                   for a, b in zip(fitted.values, start.values, strict=True))
    assert _snr(case, out) > _snr(case, case["start"]) + 3.0


@pytest.mark.render
def test_fit_resumes_from_its_checkpoint(case, monkeypatch):
    """A fit interrupted after its checkpoint at iteration 4 and run again ends where an
    uninterrupted fit of the same settings ends (to rounding: the gradients' atomic sums
    over threads run in no fixed order)."""
    from sparse_brdf.fitting import fit_images as module

    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    kw = dict(iterations=6, lr=0.05, spp=SPP, seed=0, progress=False, checkpoint_every=2)
    whole = fit_images(case["scene"], views, case["start"],
                       checkpoint_dir=case["work"] / "ckpt-whole", **kw)
    step, calls = module.take_step, []

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return step(*args, **kwargs)

    ckpt = case["work"] / "ckpt"
    monkeypatch.setattr(module, "take_step", interrupted)
    with pytest.raises(KeyboardInterrupt):
        fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt, **kw)
    monkeypatch.setattr(module, "take_step", step)
    again = fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt, **kw)
    assert whole.resumed_from == 0 and again.resumed_from == 4
    np.testing.assert_allclose(again.snr_db, whole.snr_db, atol=1e-4)
    for a, b in zip(whole.model.values, again.model.values, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * np.abs(b).max())
    # a checkpoint of another fit (another learning rate) is refused, not resumed
    with pytest.raises(UsageError, match="another fit"):
        fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt,
                   **{**kw, "lr": 0.01})


@pytest.mark.parametrize("bad", ["missing-view", "variant", "lr-end",
                                 "output-is-start", "corrupt-start", "view-key",
                                 "view-own-option", "view-no-key", "view-missing-map",
                                 "prior-weight", "validate-every", "validation-key",
                                 "validation-missing"])
def test_fit_images_bad_input_is_one_line(capsys, case, tmp_path, bad):
    view, start = f"{case['paths'][0]}:envrot=0", case["start"]
    extra: list = []
    named = ""
    if bad == "missing-view":
        view, named = str(tmp_path / "nope.exr"), "nope.exr"
    elif bad == "variant":
        extra, named = ["--variant", "scalar_rgb"], "scalar_rgb"
    elif bad == "lr-end":
        extra, named = ["--lr-end", "0"], "--lr-end"
    elif bad == "view-key":  # not a default of the scene
        view, named = f"{case['paths'][0]}:envrot=0,bogus=1", "--view"
    elif bad == "view-own-option":  # spp has an option of its own
        view, named = f"{case['paths'][0]}:spp=4", "--spp"
    elif bad == "view-no-key":
        view, named = f"{case['paths'][0]}:=4", "--view"
    elif bad == "view-missing-map":  # a view's own map that is not on this machine
        view, named = f"{case['paths'][0]}:envmap=no-such-map.exr", "no-such-map.exr"
    elif bad == "prior-weight":
        extra, named = ["--prior-weight", "-1"], "--prior-weight"
    elif bad == "validate-every":
        extra, named = ["--validate-every", "0"], "--validate-every"
    elif bad == "validation-key":  # a validation view is checked as a view is
        extra = ["--validation-view", f"{case['paths'][1]}:envrot=180,bogus=1"]
        named = "--validation-view"
    elif bad == "validation-missing":
        extra, named = ["--validation-view", str(tmp_path / "gone.exr")], "gone.exr"
    elif bad == "corrupt-start":
        start = tmp_path / "broken.sbrdf"
        start.write_bytes(case["start"].read_bytes()[:100])
        named = "broken.sbrdf"
    out = start if bad == "output-is-start" else tmp_path / "out.sbrdf"
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run(capsys, "fit-images", "sphere.xml", "--view", view, "--start", start,
                       "-o", out, "--iterations", 1, "--spp", 1, *extra)
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert named in err or bad == "output-is-start", err
    if bad.startswith("view-"):
        assert "--view" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


@pytest.mark.render
def test_readme_inverse_rendering_example_runs(case, tmp_path):
    """The README's loop, as printed there, lowers its loss from the perturbed start."""
    import re

    import drjit as dr
    import mitsuba as mi

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, re.S)
    code = next(b for b in blocks if "mi.ad.Adam" in b)
    code = code.replace("    dr.backward(loss)", "    losses.append(float(loss.array[0]))\n"
                        "    dr.backward(loss)")
    env = {"reference": str(MATERIAL), "start": str(case["start"]), "losses": []}
    exec(compile(code, "README.md", "exec"), env)
    losses = env["losses"]
    assert len(losses) == 10 and all(np.isfinite(losses))
    assert losses[-1] < 0.8 * losses[0], losses
    assert isinstance(env["scene"], mi.Scene) and dr.grad_enabled(env["opt"][env["keys"][0]])


@pytest.mark.render
def test_render_sets_scene_defaults(capsys, tmp_path):
    """``render -D KEY=VALUE`` sets a scene default (the views of a fit are rendered so);
    a malformed one, or one whose own option says otherwise, is one line and exit 2."""
    from sparse_brdf.evaluation.images import read_exr

    imgs = {}
    for rot in (0, 90):
        out = tmp_path / f"r{rot}.exr"
        code, _, err = run(capsys, "render", "sphere.xml", "-o", out, "--material",
                           f"material={MATERIAL}", "--spp", 2, "--res", 16, "-D",
                           f"envrot={rot}", "--sampling", SHARED_PATHS)
        assert code == 0, err
        imgs[rot] = read_exr(out)
    direct = render_scene(find_scene("sphere.xml"), {"material": str(MATERIAL)}, spp=2,
                          seed=0, res=16, params={"envrot": 90})
    assert np.array_equal(imgs[90], direct) and not np.array_equal(imgs[0], imgs[90])
    for bad, named in ((["--spp", 2, "-D", "spp=3"], "--spp"), (["-D", "envrot"], "KEY=VALUE")):
        code, _, err = run(capsys, "render", "sphere.xml", "-o", tmp_path / "x.exr", *bad)
        assert code == 2 and len(err.splitlines()) == 1 and named in err, err
    assert not (tmp_path / "x.exr").exists()


def _uniform_map(path: Path, rgb) -> str:
    """A small constant environment map (an EXR file) at ``path``; its absolute path."""
    return str(write_exr(path, np.broadcast_to(np.float32(rgb), (8, 16, 3)).copy()))


@pytest.mark.render
def test_views_carry_their_own_envmap(capsys, case, tmp_path):
    """A view's ``envmap`` is rendered with that map: the start's own render under a red
    map is matched exactly (shared sample paths) by a view that names the map, and not by
    one that keeps the scene's studio map; both parse from ``--view`` specs."""
    from sparse_brdf.fitting.fit_images import parse_view

    red = _uniform_map(tmp_path / "red.exr", (1.0, 0.1, 0.1))
    path, params = parse_view(f"ref.exr:envmap={red},envrot=90,envtilt=30")
    assert path == "ref.exr" and params == {"envmap": red, "envrot": "90", "envtilt": "30"}
    own = render_scene(case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0,
                       res=RES, params=params)
    kw = dict(iterations=1, spp=SPP, seed=0, progress=False)
    # snr_db[0] is the views' SNR before the first step, i.e. of the start itself
    exact = fit_images(case["scene"], views_for([params], [own]), case["start"], **kw)
    studio = fit_images(case["scene"], views_for([{"envrot": 90, "envtilt": 30}], [own]),
                        case["start"], **kw)
    assert exact.snr_db[0] > 60.0, exact.snr_db
    assert studio.snr_db[0] < 20.0, studio.snr_db
    # and on the command line
    ref = write_exr(tmp_path / "red-ref.exr", own)
    out = tmp_path / "fitted.sbrdf"
    code, stdout, err = run(capsys, "fit-images", "sphere.xml", "--view",
                            f"{ref}:envmap={red},envrot=90,envtilt=30", "--start",
                            case["start"], "-o", out, "--iterations", 1, "--spp", SPP)
    assert code == 0, err
    assert re.search(r"SNR (\d+\.\d) dB at the start", stdout), stdout
    assert float(re.search(r"SNR (\d+\.\d) dB at the start", stdout).group(1)) > 60.0


@pytest.mark.render
def test_envtilt_default_leaves_the_scene_unchanged(tmp_path):
    """``sphere.xml``'s ``envtilt`` (a rotation of the map about +x after ``envrot``)
    is 0 by default, and then renders bit for bit as the scene without it; a tilt moves
    the lighting."""
    from sparse_brdf.paths import SCENES_DIR

    text = (SCENES_DIR / "sphere.xml").read_text()
    line = '            <rotate x="1" angle="$envtilt"/>\n'
    assert line in text
    untilted = tmp_path / "sphere-untilted.xml"
    untilted.write_text(text.replace(line, ""))
    studio = str(SCENES_DIR / "envmaps" / "studio.exr")
    kw = dict(spp=2, seed=0, res=RES)
    new = render_scene(find_scene("sphere.xml"), {"material": str(MATERIAL)},
                       params={"envrot": 90}, **kw)
    old = render_scene(untilted, {"material": str(MATERIAL)},
                       params={"envrot": 90, "envmap": studio}, **kw)
    assert np.array_equal(new, old)
    tilted = render_scene(find_scene("sphere.xml"), {"material": str(MATERIAL)},
                          params={"envrot": 90, "envtilt": 30}, **kw)
    assert not np.allclose(new, tilted, rtol=0.05)


@pytest.mark.render
def test_scenes_sharing_a_model_keep_their_own_values(case):
    """The plugin reuses the last grouped build for scenes holding the same model and
    values (an image fit's views): new values in one scene do not leak into another."""
    import mitsuba as mi

    from sparse_brdf.evaluation.render import load_scene

    scenes = [load_scene(case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0,
                         res=RES) for _ in range(2)]
    before = [np.array(mi.render(s, spp=SPP, seed=0)) for s in scenes]
    assert np.array_equal(before[0], before[1])
    params = mi.traverse(scenes[0])
    key = next(k for k in params.keys() if k.endswith("values_0"))
    params[key] = mi.Float(np.array(params[key]) * 2.0)
    params.update()
    brighter = np.array(mi.render(scenes[0], spp=SPP, seed=0))
    again = np.array(mi.render(scenes[1], spp=SPP, seed=0))
    assert not np.allclose(brighter, before[0], rtol=0.01)
    assert np.array_equal(again, before[1])


@pytest.mark.render
def test_lbfgs_fit_improves_and_resumes(case):
    """``optimizer="lbfgs"``: L-BFGS-B on the shared-path loss lifts the views' SNR from
    the perturbed start within a few evaluations; its checkpoint holds the best values,
    which a rerun of the same fit returns; an unknown optimizer is a UsageError."""
    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    kw = dict(iterations=8, spp=SPP, seed=0, progress=False, optimizer="lbfgs",
              checkpoint_every=4)
    ckpt = case["work"] / "ckpt-lbfgs"
    fit = fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt, **kw)
    assert 1 < len(fit.snr_db) <= 8 and fit.iterations == len(fit.snr_db)
    assert max(fit.snr_db) > fit.snr_db[0] + 3.0, fit.snr_db
    out = save_sbrdf(case["work"] / "lbfgs.sbrdf", fit.model)
    assert _snr(case, out) > _snr(case, case["start"]) + 3.0
    again = fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt, **kw)
    assert again.resumed_from == 8 and again.snr_db == fit.snr_db
    for a, b in zip(fit.model.values, again.model.values, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(UsageError, match="optimizer"):
        fit_images(case["scene"], views, case["start"], **{**kw, "optimizer": "sgd"})


@pytest.mark.render
def test_log_loss_is_the_views_mean_snr(case):
    """``loss="log"`` optimises the mean of the views' SNRs in dB: its first record is
    exactly that mean for the start (the views' renders share the references' paths),
    while the relative loss records the SNR of the views' mean relative error."""
    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    kw = dict(iterations=1, spp=SPP, seed=0, progress=False)
    per_view = [render_snr(case["refs"][r], render_scene(
        case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0, res=RES,
        params={"envrot": r})) for r in ROTS]
    log = fit_images(case["scene"], views, case["start"], loss="log", **kw)
    rel = fit_images(case["scene"], views, case["start"], **kw)
    assert log.snr_db[0] == pytest.approx(np.mean(per_view), abs=1e-3)
    mean_error = np.mean([10 ** (-s / 10) for s in per_view])
    assert rel.snr_db[0] == pytest.approx(-10 * np.log10(mean_error), abs=1e-3)
    with pytest.raises(UsageError, match="loss"):
        fit_images(case["scene"], views, case["start"], loss="l1", **kw)


def _start_values(case) -> list[np.ndarray]:
    """The start file's values, in the order a fit's model holds them."""
    return [np.asarray(v, np.float32) for v in load_sbrdf(case["start"]).values]


@pytest.mark.render
def test_prior_weight_keeps_the_values_near_the_start(case):
    """``prior_weight`` adds ``w * mean((u - 1)^2)`` to the loss, ``u`` each value over
    its starting scale: the L-BFGS fit returns its best objective, so the penalty of its
    values is at most the start's loss (which costs no penalty), a bound the fit without
    it breaks; Adam follows the penalty's gradient too; a negative weight is refused."""
    from sparse_brdf.fitting.fit_images import SCALE_FLOOR

    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    kw = dict(iterations=6, spp=SPP, seed=0, progress=False, optimizer="lbfgs")
    start = _start_values(case)
    scales = [np.maximum(np.abs(s), SCALE_FLOOR * np.abs(s).max()) for s in start]

    def penalty(fit) -> float:
        """mean((u - 1)^2) over all values."""
        return float(np.mean(np.concatenate([np.square((v - s) / c) for v, s, c in
                                             zip(fit.model.values, start, scales,
                                                 strict=True)])))

    weight = 1e3
    free = fit_images(case["scene"], views, case["start"], **kw)
    held = fit_images(case["scene"], views, case["start"], prior_weight=weight, **kw)
    start_loss = 10 ** (-free.snr_db[0] / 10)  # the views' mean relative error
    assert held.snr_db[0] == free.snr_db[0]  # the record is the views' loss alone
    assert penalty(free) * weight > start_loss  # the free fit moves further than that
    assert 0 < penalty(held) * weight <= start_loss * (1 + 1e-4)
    # Adam takes the penalty's gradient too
    adam = dict(iterations=4, lr=0.05, spp=SPP, seed=0, progress=False)
    pulled = fit_images(case["scene"], views, case["start"], prior_weight=1e4, **adam)
    loose = fit_images(case["scene"], views, case["start"], **adam)
    assert penalty(pulled) < penalty(loose)
    with pytest.raises(UsageError, match="prior_weight"):
        fit_images(case["scene"], views, case["start"], prior_weight=-1.0, **kw)


@pytest.mark.render
def test_validation_returns_the_iterate_it_rates_best(case, tmp_path):
    """Validation views are never fitted: the fit measures them at the start and every
    ``validate_every`` evaluations, reports each SNR, and returns the iterate they rate
    best. With the start's own render as the validation reference, every move away from
    the start looks worse, so the start comes back unchanged; with the material's
    reference, the returned iterate is the one the callback saw at the best record; a
    rerun resumes the record from the checkpoint."""
    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    kw = dict(iterations=6, spp=SPP, seed=0, progress=False, optimizer="lbfgs",
              validate_every=2)
    own = render_scene(case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0,
                       res=RES, params={"envrot": 90})
    fit = fit_images(case["scene"], views, case["start"],
                     validation=views_for([{"envrot": 90}], [own]), **kw)
    assert fit.best_evaluation == 0 and fit.validation_snr_db[0][0] == 0
    assert fit.validation_snr_db[0][1] > 100  # the very same render
    assert len(fit.validation_snr_db) >= 3
    for a, b in zip(fit.model.values, _start_values(case), strict=True):
        np.testing.assert_array_equal(a, b)
    # the material's own reference at a view the fit does not see
    ref90 = render_scene(case["scene"], {"material": str(MATERIAL)}, spp=SPP, seed=0,
                         res=RES, params={"envrot": 90})
    seen = {}
    ckpt = tmp_path / "ckpt"
    fit = fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt,
                     validation=views_for([{"envrot": 90}], [ref90]),
                     callback=lambda n, model: seen.setdefault(n, model), **kw)
    record = dict(fit.validation_snr_db)
    assert sorted(seen) == sorted(record) and set(record) >= {0, 2, 4}
    assert record[fit.best_evaluation] == max(record.values())
    assert record[0] == pytest.approx(render_snr(ref90, render_scene(
        case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0, res=RES,
        params={"envrot": 90})), abs=1e-3)
    assert max(record.values()) > record[0] + 1.0
    for a, b in zip(fit.model.values, seen[fit.best_evaluation].values, strict=True):
        np.testing.assert_array_equal(a, b)
    again = fit_images(case["scene"], views, case["start"], checkpoint_dir=ckpt,
                       validation=views_for([{"envrot": 90}], [ref90]), **kw)
    # with the log loss, the validation's SNR is its views' mean SNR (as the loss's)
    refs = views_for([{"envrot": 90}, {"envrot": 0}], [ref90, case["refs"][0]])
    log = fit_images(case["scene"], views[1:], case["start"], validation=refs, loss="log",
                     **{**kw, "iterations": 1})
    per_view = [render_snr(v.image, render_scene(
        case["scene"], {"material": str(case["start"])}, spp=SPP, seed=0, res=RES,
        params=v.params)) for v in refs]
    assert log.validation_snr_db[0][1] == pytest.approx(np.mean(per_view), abs=1e-3)
    assert again.resumed_from == 6 and again.best_evaluation == fit.best_evaluation
    assert again.validation_snr_db == fit.validation_snr_db
    for a, b in zip(fit.model.values, again.model.values, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.render
def test_fit_images_command_validation_view_and_prior(capsys, case, tmp_path):
    """``--validation-view`` and ``--prior-weight`` reach the fit: it reports the
    iterate it kept, and writes it."""
    ref90 = write_exr(tmp_path / "ref90.exr", render_scene(
        case["scene"], {"material": str(MATERIAL)}, spp=SPP, seed=0, res=RES,
        params={"envrot": 90}))
    out = tmp_path / "fitted.sbrdf"
    code, stdout, err = run(capsys, "fit-images", "sphere.xml", "--view",
                            f"{case['paths'][0]}:envrot=0", "--start", case["start"],
                            "-o", out, "--iterations", 4, "--optimizer", "lbfgs",
                            "--spp", SPP, "--validation-view", f"{ref90}:envrot=90",
                            "--validate-every", 2, "--prior-weight", 1e-6)
    assert code == 0, err
    assert re.search(r"kept the iterate after \d+ evaluations", stdout), stdout
    assert out.is_file()


@pytest.mark.render
def test_a_fit_does_not_flood_stderr(capfd, case):
    """Differentiating the plugin's loops logs nothing: Dr.Jit's warning per traced loop
    (``ad_loop(...): forcing conditional statement to symbolic mode``) once wrote
    thousands of lines per fit into the progress bar's terminal."""
    views = views_for([{"envrot": r} for r in ROTS], [case["refs"][r] for r in ROTS])
    capfd.readouterr()
    for optimizer in ("adam", "lbfgs"):
        fit_images(case["scene"], views, case["start"], iterations=2, spp=SPP,
                   optimizer=optimizer, progress=False)
    err = capfd.readouterr().err
    assert "ad_loop" not in err and "forcing" not in err, err[:300]
