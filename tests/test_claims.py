"""Claims: each verdict's numbers on hand-computed synthetic results, the claims file's errors,
and a user-declared claim through ``formula-tourney report``."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from report_fixtures import build_tournament

from formula_tourney.claims.schema import Claim, shipped_set
from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.report.claims import profiles
from formula_tourney.report.claims.evaluate import PAPER_PRESET, evaluate, preset_of
from formula_tourney.report.claims.evidence import compare_scores, overall
from formula_tourney.report.claims.sources import load_claims_file, resolve_claims
from formula_tourney.report.claims.table import claims_table
from formula_tourney.report.load import load_tournament
from formula_tourney.report.paper_tables import Context, table2
from formula_tourney.results.folder import JobFolder
from formula_tourney.tourney.spec import parse_spec
from formula_tourney.training.loop import train
from formula_tourney.training.run_spec import RunSpec, build_run_spec

E2 = 2.0 * math.exp(-2.0)  # the fixture template's learning term at episode 300


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("results")
    build_tournament(base)
    return base


@pytest.fixture(scope="module")
def ctx(results: Path) -> Context:
    return Context.build(load_tournament(results / "fixture-cup"))


def cli(*args: str) -> int:
    """``formula-tourney ARGS``'s exit code."""
    try:
        main(list(args))
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0


def claim(**kw) -> Claim:
    return Claim.model_validate({"id": "c", "statement": "s", **kw})


def test_two_samples_by_hand() -> None:
    st = compare_scores([1.0, 2.0, 3.0], [0.0, 0.5, 1.0])
    assert st.effect == pytest.approx(1.5)
    # pairs A > B: 1 beats 0 and 0.5 and ties 1 (2.5), 2 and 3 beat all three: 8.5 of 9
    assert st.prob == pytest.approx(8.5 / 9)
    # pooled variance (2*1 + 2*0.25) / 4 = 0.625; 2 (1.96 + 0.8416)^2 0.625 / 1.5^2 = 4.36 -> 5
    assert st.seeds_needed == 5
    assert 0.0 < st.effect_low < 1.5 < st.effect_high and st.verdict == "supported"


def test_against_a_bot_the_bot_is_a_constant() -> None:
    laps = [27.1, 27.4, 27.2]
    st = compare_scores([-x for x in laps], [-28.57], b_fixed=True)
    assert st.effect == pytest.approx(28.57 - np.mean(laps))
    assert st.prob == 1.0 and st.prob_low == 1.0 and st.verdict == "supported"
    assert st.n_a == 3 and st.n_b == 1
    # one-sample rule: (1.96 + 0.8416)^2 var / d^2 with var 0.0233, d 1.337 -> 0.10 -> 2
    assert st.seeds_needed == 2
    with pytest.raises(ValueError):
        compare_scores([1.0], [1.0, 2.0], b_fixed=True)


def test_runs_without_a_clean_lap_lose_and_decide_by_probability() -> None:
    st = compare_scores([-math.inf, -math.inf], [-30.0, -31.0])
    assert math.isnan(st.effect) and st.prob == 0.0 and st.verdict == "contradicted"
    st = compare_scores([-29.0, -math.inf], [-30.0, -31.0])
    # 29 beats both; the DNF loses both: P = 2/4, effect over finishers 30.5 - 29
    assert st.prob == pytest.approx(0.5) and st.effect == pytest.approx(1.5)
    assert st.finite_a == 1 and st.verdict == "inconclusive"  # one finisher: no interval


def test_no_runs_is_no_data_and_overall_rules() -> None:
    assert compare_scores([], [1.0, 2.0]).verdict == "no data"
    assert overall(["supported", "supported"]) == "supported"
    assert overall(["supported", "inconclusive"]) == "inconclusive"
    assert overall(["supported", "contradicted"]) == "contradicted"
    assert overall(["no data", "no data"]) == "no data"


def test_a_claim_decided_on_wins_reads_who_wins_each_pair(ctx: Context) -> None:
    """win1's three laps (27.1, 27.4, 27.2 s) all beat the follower's 28.57 s: three wins,
    too few to decide (a consistent effect needs seven), shown as P(A better)."""
    res = evaluate(ctx, claim(kind="faster", track="oval", decide_on="wins",
                              a={"part": "part1", "entrant": "win1"}, b={"bot": "follower"}))
    seq = res.comparisons[0].stats.sequence
    assert seq is not None and seq.n == 3 and seq.mean == 1.0 and seq.verdict == "open"
    assert res.sequential == "inconclusive" and res.verdict == "supported"  # fixed-sample CI
    row = claims_table([res], "test").records[0]
    assert row["decide_on"] == "wins"
    text = claims_table([res], "test").rows[0]["text"][("claims", "95% CS")]
    lo, hi = ((seq.low + 1) / 2, (seq.high + 1) / 2)
    assert text == f"P [{lo:.2f}, {hi:.2f}]" and hi == 1.0 and lo < 0.5
    # the paper's claims are all decided on wins
    assert {c.decide_on for c in shipped_set("paper").resolved()} == {"wins"}


def test_user_claim_on_the_fixture_by_hand(ctx: Context) -> None:
    """win1 vs win4 in part1 on the oval: win1's best laps are written by hand (27.1, 27.4,
    27.2), win4's are the template's 26.5 + 0.3 + 2 e^-2 + 0.1 seed."""
    res = evaluate(ctx, claim(kind="faster", track="oval",
                              a={"part": "part1", "entrant": "win1"},
                              b={"part": "part1", "entrant": "win4"}))
    (comp,) = res.comparisons
    win4 = [26.8 + E2 + 0.1 * s for s in range(3)]
    assert sorted(-x for x in comp.a_scores) == pytest.approx([27.1, 27.2, 27.4])
    assert sorted(-x for x in comp.b_scores) == pytest.approx(win4)
    assert comp.stats.effect == pytest.approx(np.mean(win4) - np.mean([27.1, 27.4, 27.2]))
    # 27.1 beats 27.17 and 27.27; 27.2 beats 27.27; 27.4 none: 3 of 9
    assert comp.stats.prob == pytest.approx(3 / 9)
    assert res.verdict == comp.stats.verdict == "inconclusive"
    # still open, and out of reach: 0.07 s on a bound of one reference limit would need more
    # than sequential.PROJECTION_LIMIT pairs, so it has no price (both sides: 600 s a run)
    assert comp.pair_cpu_s == 1200.0 and comp.pairs_to_decide is None
    assert math.isnan(comp.cpu_h_to_decide)


def test_bot_claim_and_finish_claim_on_the_fixture(ctx: Context) -> None:
    res = evaluate(ctx, claim(kind="faster", track="oval", a={"part": "part1", "entrant":
                                                                "win1"}, b={"bot": "follower"}))
    assert res.comparisons[0].stats.effect == pytest.approx(28.57 - np.mean([27.1, 27.4, 27.2]))
    assert res.verdict == "supported"
    assert res.comparisons[0].pair_cpu_s == 600.0  # the bot's side costs nothing
    # its CS reads the differences' span against one fixed lap: no run beats the bot by more
    # than the bot's distance from the oval's limit (28.57 - 25.80 s)
    seq = res.comparisons[0].stats.sequence
    assert seq is not None and seq.high <= 28.57 - 25.80 + 1e-9
    # per1m-rc of part3 laps both unseen tracks cleanly (100 %); per1m-mot's one finished run
    # never laps flowing (50 %); its second run is still running and has no result
    res = evaluate(ctx, claim(kind="finishes_more", a={"part": "part3", "entrant": "per1m-rc"},
                              b={"part": "part3", "entrant": "per1m-mot"}))
    st = res.comparisons[0].stats
    assert res.comparisons[0].a_scores == [100.0, 100.0]
    assert res.comparisons[0].b_scores == [50.0]
    assert st.effect == pytest.approx(50.0) and st.prob == 1.0
    assert res.verdict == "inconclusive"  # one run of B: no interval at this sample size


def test_reward_claim_split_and_missing_runs(ctx: Context) -> None:
    paper = {c.id: c for c in shipped_set("paper").resolved()}
    res = evaluate(ctx, paper["paper-6"])  # the fixture's ablation: ceilings 1000 vs 800
    assert res.comparisons[0].a_runs == ["ablation/win1/seed-0", "ablation/win1/seed-1"]
    assert res.comparisons[0].stats.effect > 150.0 and res.verdict == "supported"
    res = evaluate(ctx, claim(kind="faster", track="technical", split_b="family",
                              a={"part": "part2", "entrant": "per1m-rc"},
                              b={"part": "part2"}))
    # B split by family, then into entrants: per1m-rc meets each other line and variant
    assert [c.label for c in res.comparisons] == [
        "per1m RC on technical vs win4 MOT on technical",
        "per1m RC on technical vs win4 RC on technical",
        "per1m RC on technical vs per1m MOT on technical"]
    res = evaluate(ctx, claim(kind="faster", track="oval", a={"variant": "WIN9"},
                              b={"bot": "follower"}))
    assert res.verdict == "no data"
    assert any("no run of this tournament matches" in n for n in res.notes)


def test_performance_profile_by_hand() -> None:
    taus = np.array([1.0, 1.05, 1.1])
    assert profiles.profile(np.array([1.0, 1.1, math.inf]), taus).tolist() == \
        pytest.approx([1 / 3, 1 / 3, 2 / 3])
    mid, low, high = profiles.profile_band(np.array([1.0, 1.1, math.inf]), taus)
    assert np.all(low <= mid) and np.all(mid <= high)


def test_claims_file_errors_name_file_line_and_allowed(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[[claim]]\nid = "x"\nstatement = "s"\nkind = "faster"\n'
                    'a = { famly = "PER" }\nb = { bot = "follower" }\n')
    with pytest.raises(UserInputError) as info:
        load_claims_file(path)
    assert f"{path}:5: claim[0].a.famly: unknown key; allowed keys: label, part" in str(info.value)
    path.write_text('[[claim]]\nid = "x"\nstatement = "s"\nkind = "slower"\n'
                    'a = {}\nb = { bot = "follower" }\n')
    with pytest.raises(UserInputError, match=rf"{path}:4: claim\[0\].kind: Input should be "
                       "'faster', 'finishes_more', 'higher_reward' or 'learns_faster'"):
        load_claims_file(path)
    path.write_text('include = ["papr"]\n')
    with pytest.raises(UserInputError, match="unknown claim set 'papr'; allowed values: paper"):
        load_claims_file(path)


def test_tournament_claims_table_is_validated_with_the_file(tmp_path: Path) -> None:
    text = ('name = "t"\n[[parts]]\nname = "p1"\nentrants = ["WIN1"]\ntrain_tracks = ["oval"]\n'
            '[claims]\ninclude = ["paper"]\n[[claims.claim]]\nid = "mine"\nstatement = "s"\n'
            'kind = "faster"\ntrack = "oval"\na = { variant = "WIN1", lacc = true }\n'
            'b = { bot = "follower" }\n')
    with pytest.raises(UserInputError, match=r"t.toml:13: claims.claim\[0\].a.lacc: unknown "
                       "key; allowed keys: label, part"):
        parse_spec(text, tmp_path / "t.toml")
    spec = parse_spec(text.replace("lacc", "lac"), tmp_path / "t.toml")
    claims, origin = resolve_claims([], {"spec": spec.model_dump_json()})
    assert [c.id for c in claims][-1] == "mine" and len(claims) == 9
    assert origin == "the tournament file's [claims]"


def test_user_declared_claim_end_to_end(results: Path, tmp_path: Path,
                                        capsys: pytest.CaptureFixture) -> None:
    path = tmp_path / "mine.claims.toml"
    path.write_text('[[claim]]\nid = "win1-beats-bot"\nstatement = "win1 beats the bot"\n'
                    'kind = "faster"\ntrack = "oval"\n'
                    'a = { part = "part1", entrant = "win1" }\nb = { bot = "follower" }\n')
    assert cli("report", "-t", "fixture-cup", "--results", str(results), "--claims",
               str(path), "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    (rec,) = doc["tables"]["claims"]["records"]
    assert rec["id"] == "win1-beats-bot" and rec["verdict"] == "supported"
    assert rec["comparisons"][0]["effect"] == pytest.approx(28.57 - np.mean([27.1, 27.4, 27.2]))
    args = ["report", "-t", "fixture-cup", "--results", str(results), "--markdown"]
    assert cli(*args, "--claims", str(path)) == 0
    assert "win1-beats-bot (supported): win1 beats the bot" in capsys.readouterr().out
    path.write_text('[[claim]]\nid = "x"\nstatement = "s"\nkind = "fast"\na = {}\nb = {}\n')
    assert cli(*args, "--claims", str(path)) == 2
    assert f"error: {path}:4: claim[0].kind" in capsys.readouterr().err


def tiny_spec(**schedule):
    base = {"episodes": 6, "max_steps": 60, "test_every_episodes": 2, "test_starts": 1,
            "test_max_steps": 40}  # fmt: skip
    return build_run_spec(variant="WIN1", train_tracks=["oval"], seed=7, device="cpu",
                          overrides={"batch_size": 16, "learning_starts": 20,
                                     "hidden": (16, 16)},
                          schedule={**base, **schedule})  # fmt: skip


def test_tests_never_change_the_training(tmp_path: Path) -> None:
    """Two real runs that differ only in their tests (how often, from how many starts, how
    long, on which tracks, with checkpoints) train the same agent: the same episodes, rewards
    and updates; their training digests agree and their full digests do not."""
    a = tiny_spec()
    b = tiny_spec(test_every_episodes=3, test_starts=2, test_max_steps=25,
                  save_test_checkpoints=True)
    b = b.model_copy(update={"test_tracks": ("oval", "technical")})
    assert a.training_digest() == b.training_digest() and a.digest() != b.digest()
    train(a, tmp_path / "a")
    train(b, tmp_path / "b")
    ea = pd.read_parquet(JobFolder(tmp_path / "a").table_path("episodes"))
    eb = pd.read_parquet(JobFolder(tmp_path / "b").table_path("episodes"))
    cols = ["episode", "reward", "steps", "env_steps", "updates", "termination"]
    pd.testing.assert_frame_equal(ea[cols], eb[cols])
    # what the training depends on does change it
    assert tiny_spec().model_copy(update={"seed": 8}).training_digest() != a.training_digest()
    assert tiny_spec(max_steps=61).training_digest() != a.training_digest()


def test_a_run_repeated_in_another_part_counts_once(ctx: Context) -> None:
    """part1's win1 seeds 0 and 1 given the same training (one spec, other tests): A keeps
    two of its three runs and says why; the effect is computed on those two."""
    data = copy.deepcopy(ctx.data)
    same = tiny_spec().to_json()
    data.configs["part1/win1/seed-0"] = same
    data.configs["part1/win1/seed-1"] = {**same, "schedule": {**same["schedule"],
                                                               "test_starts": 3}}
    dup_ctx = Context.build(data)
    res = evaluate(dup_ctx, claim(kind="faster", track="oval",
                                  a={"part": "part1", "entrant": "win1"},
                                  b={"part": "part1", "entrant": "win4"}))
    (comp,) = res.comparisons
    assert comp.a_runs == ["part1/win1/seed-0", "part1/win1/seed-2"]
    assert "A: 1 run(s) repeating another run's training" in comp.note
    # the performance profile counts the repeated run once too
    from_profile = profiles.run_ratios(dup_ctx)["job_id"].tolist()
    assert "part1/win1/seed-1" not in from_profile and "part1/win1/seed-0" in from_profile
    # the fixture's ablation WIN1 repeats part1's WIN1 training seed for seed: counted once
    plain = profiles.run_ratios(ctx)["job_id"].tolist()
    assert "part1/win1/seed-0" in plain and "ablation/win1/seed-0" not in plain
    # B drops a run that repeats one of A's
    data.configs["part1/win4/seed-2"] = same
    res = evaluate(Context.build(data), claim(kind="faster", track="oval",
                                              a={"part": "part1", "entrant": "win1"},
                                              b={"part": "part1", "entrant": "win4"}))
    assert res.comparisons[0].b_runs == ["part1/win4/seed-0", "part1/win4/seed-1"]


FAST = ["preset fast-small"]
TUNED_BC = ["preset tuned-bc", "demos (follower on mincurv)"]


def with_presets(ctx: Context, presets: dict[str, tuple[str, list[str]]]) -> Context:
    """The fixture with the jobs under each prefix trained from another preset: its name in the
    run spec and its beyond-paper labels, as ``training.loop`` writes them to config.json."""
    data = copy.deepcopy(ctx.data)
    for job_id in list(data.configs):
        for prefix, (preset, labels) in presets.items():
            if job_id.startswith(prefix):
                data.configs[job_id] = {**data.configs[job_id], "preset": preset}
                data.beyond_paper[job_id] = list(labels)
    return Context.build(data)


def test_two_presets_of_one_variant_are_never_pooled(ctx: Context) -> None:
    """WIN1 on the oval from two presets (part1's three seeds fast-small, the ablation's two
    tuned-bc with demos): two entrants in every claim and in the profile, selectable by preset
    and label, and compared with runs of their own setup only."""
    two = with_presets(ctx, {"part1/win1/": ("fast-small", FAST),
                             "ablation/win1/": ("tuned-bc", TUNED_BC)})
    fast = ["part1/win1/seed-0", "part1/win1/seed-1", "part1/win1/seed-2"]
    tuned = ["ablation/win1/seed-0", "ablation/win1/seed-1"]
    res = evaluate(two, claim(kind="faster", track="oval", b={"bot": "follower"},
                              a={"variant": "win1", "settings": {"adopted_target": True}}))
    assert [(c.label, c.a_runs) for c in res.comparisons] == [
        ("win1 MOT on oval (beyond paper: preset fast-small) vs follower bot on recorded", fast),
        ("win1 MOT on oval (beyond paper: preset tuned-bc, demos (follower on mincurv)) "
         "vs follower bot on recorded", tuned)]
    # the fixture's win1 laps by hand against the follower's 28.57 s
    assert res.comparisons[0].stats.effect == pytest.approx(28.57 - np.mean([27.1, 27.4, 27.2]))
    # a claim that pools says so, and gets one sample of five runs
    pooled = evaluate(two, claim(kind="faster", track="oval", b={"bot": "follower"},
                                 pool=["setup"], a={"variant": "win1",
                                                    "settings": {"adopted_target": True}}))
    (comp,) = pooled.comparisons
    assert comp.a_runs == fast + tuned
    assert comp.label == "win1 MOT on oval vs follower bot on recorded"
    # selecting by preset and by label (a run spec without a preset is the paper's)
    assert RunSpec.model_fields["preset"].default == PAPER_PRESET
    assert preset_of(two, "part1/win4/seed-0") == PAPER_PRESET
    for group, runs in (({"preset": "tuned-bc"}, tuned), ({"preset": "fast*"}, fast),
                        ({"beyond_paper": "demos*"}, tuned),
                        ({"variant": "win1", "beyond_paper": []},
                         ["ablation/win1-noat/seed-0", "ablation/win1-noat/seed-1"])):
        res = evaluate(two, claim(kind="faster", track="oval", a=group, b={"bot": "follower"}))
        assert [r for c in res.comparisons for r in c.a_runs] == runs
    # runs against runs: only entrants of one setup meet; part1's win4 is of the paper's
    res = evaluate(two, claim(kind="faster", track="oval", a={"preset": "fast-small"},
                              b={"part": "part1", "variant": "win4"}))
    assert res.comparisons == [] and res.verdict == "no data"
    assert any("no entrant of A has one of B with the same setup" in n for n in res.notes)
    res = evaluate(two, claim(kind="faster", track="oval", a={"preset": "fast-small"},
                              b={"part": "part1", "variant": "win4"}, pool=["setup"]))
    assert [c.label for c in res.comparisons] == ["win1 MOT on oval vs win4 MOT on oval"]
    # the profile: one curve per preset, never "win1 (n=5)"
    ratios = profiles.run_ratios(two)
    by_group = ratios.groupby("group", sort=False)["job_id"].apply(list).to_dict()
    assert by_group["win1 MOT on oval (beyond paper: preset fast-small)"] == fast
    assert by_group["win1 MOT on oval (beyond paper: preset tuned-bc, demos (follower on "
                    "mincurv))"] == tuned
    assert ratios["setup"].nunique() == 3  # fast-small, tuned-bc + demos, the paper's


def test_table2_rows_name_their_preset(ctx: Context) -> None:
    """part2's per1m-rc trained fast-small: its own Table 2 row beside part3's paper-setup
    per1m RC, each with its own best lap (template: 66 + 1.5 + 2 e^-2, seed 0)."""
    two = with_presets(ctx, {"part2/per1m-rc/": ("fast-small", FAST)})
    rows = {r["row"]: r for r in table2(two).records if r["track"] == "technical"}
    assert "per1m RC (beyond paper: preset fast-small)" in rows and "per1m RC" in rows
    assert rows["per1m RC (beyond paper: preset fast-small)"]["runs"] == 3
    assert rows["per1m RC"]["runs"] == 2  # part3's two seeds
    assert rows["per1m RC"]["bLT"] == pytest.approx(67.5 + E2)


def test_paper_2_rc_reads_racing_line_runs_with_lac(ctx: Context) -> None:
    """The paper's finding 2 on the fixture: part2's per1m RC and win4 RC, part3's per1m RC
    and per1m RC + LAC, each an entrant of its own against the follower on technical."""
    paper = {c.id: c for c in shipped_set("paper").resolved()}
    res = evaluate(ctx, paper["paper-2-rc"])
    assert [c.label for c in res.comparisons] == [
        f"{a} on technical vs follower bot on recorded"
        for a in ("win4 RC", "per1m RC", "per1m RC + LAC")]
    lac = res.comparisons[2]
    assert lac.a_runs == ["part3/per1m-rc-lac/seed-0", "part3/per1m-rc-lac/seed-1"]
    assert lac.stats.verdict == "supported"  # 65 + 2 e^-2 (+0.1) against 68.11


def test_a_per_track_claim_compares_only_runs_that_drive_the_track(ctx: Context) -> None:
    """win4 against per1m on each of win4's train tracks: on technical, part1's oval-trained
    per1m (never tested on technical) is no comparison, where part3's technical-trained per1m
    tested on the oval is one on the oval; every comparison has runs on both sides."""
    res = evaluate(ctx, claim(kind="faster", per_track=True, a={"variant": "win4"},
                              b={"variant": "per1m"}))
    labels = {(c.track, c.label.split(" vs ")[1]) for c in res.comparisons}
    assert ("technical", "per1m MOT on oval") not in labels
    assert ("oval", "per1m RC on technical") in labels  # tested on the oval (part3)
    assert all(c.a_runs and c.b_runs for c in res.comparisons)
    assert res.verdict == "contradicted"
