"""``evp wifi``: WiFi RSS fingerprinting (seed 001) on data in the UJI long-term layout."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from evp.io.output_paths import writable_file

app = typer.Typer(help="WiFi RSS fingerprinting: build a radio map, locate scans, compare methods.", no_args_is_help=True)
METHOD_HELP = (
    "knn3 (plain 3-NN), wknn_paper (seed 001: weighted 3-NN on averaged fingerprints) or wknn_cv (weighted k-NN, floor detection, k by cross-validation)."
)


def _tuning_progress(settings, label: str):
    """Progress of the leave-one-place-out choice of k, on stderr (stdout keeps the results)."""
    from evp.cli.progress import progress_of

    return progress_of(label, len(settings.wifi.k_candidates), "values of k")


@app.command("build")
def wifi_build(
    folder: Path = typer.Argument(..., help="UJI long-term database folder (dbNN/ or the folder holding one)."),
    out: Path = typer.Option(..., "--out", help="Radio map file to write (.npz)."),
) -> None:
    """Build a radio map from the survey set (trn01)."""
    from evp.io.wifi_uji import SURVEY_SET, database_folder, read_set, save_radio_map
    from evp.wifi.fingerprints import reference_points

    writable_file(out, example="radio_map.npz")
    settings_tolerance = _settings(None).wifi.place_tolerance_m
    survey = read_set(database_folder(folder), SURVEY_SET)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_radio_map(survey, out)
    _, places = reference_points(survey, settings_tolerance)
    typer.echo(f"{out}: {len(survey)} samples at {places} places, {len(survey.access_points)} access points")


@app.command("locate")
def wifi_locate(
    radio_map: Path = typer.Argument(..., help="Radio map from evp wifi build."),
    scans: Path = typer.Argument(..., help="Scans to locate: an SSSnnrss.csv file (one scan a row, 100 = not heard)."),
    method: str = typer.Option("wknn_cv", "--method", help=METHOD_HELP),
    json_out: Path | None = typer.Option(None, "--json", help="Also write the positions as JSON."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (its wifi section)."),
) -> None:
    """Locate each scan: x y floor per row, or why it was not located."""
    from evp.io.wifi_uji import load_radio_map, read_scans
    from evp.wifi.knn import build_radio_map, locate
    from evp.wifi.methods import TUNED, method_named

    writable_file(json_out, "--json", "positions.json")
    settings = _settings(config)
    survey = load_radio_map(radio_map)
    if method == TUNED.name:
        with _tuning_progress(settings, "choosing k (leave-one-place-out)") as progress:
            chosen = method_named(method, survey, settings.wifi, progress.advance)
    else:
        chosen = method_named(method, survey, settings.wifi)
    found = locate(
        build_radio_map(survey, chosen, settings.wifi.not_detected_dbm, settings.wifi.place_tolerance_m), read_scans(scans, len(survey.access_points)), chosen
    )
    rows = []
    for row, (position, floor, heard) in enumerate(zip(found.positions, found.floors, found.known_heard), start=1):
        if heard:
            typer.echo(f"{row} {position[0]:.2f} {position[1]:.2f} {floor}")
            rows.append({"row": row, "x_m": float(position[0]), "y_m": float(position[1]), "floor": int(floor)})
        else:
            typer.echo(f"{row} not located: the scan heard no access point of the radio map")
            rows.append({"row": row, "located": False, "reason": "no known access point heard"})
    if json_out is not None:
        json_out.write_text(json.dumps({"method": chosen.name, "k": chosen.k, "scans": rows}, indent=1))


@app.command("eval")
def wifi_eval(
    folder: Path = typer.Argument(..., help="UJI long-term database folder (dbNN/ with trn01 and tst*, or the folder holding one)."),
    json_out: Path | None = typer.Option(None, "--json", help="Write the scores as JSON."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (its wifi section)."),
) -> None:
    """Score knn3, wknn_paper and wknn_cv on every test set: mean 2-D error and floor accuracy, per
    set, overall and on the test points that are not in the radio map."""
    from evp.io.wifi_uji import read_database
    from evp.wifi.evaluation import evaluate_methods
    from evp.wifi.methods import compared_methods

    writable_file(json_out, "--json", "scores.json")
    settings = _settings(config)
    survey, tests = read_database(folder)
    with _tuning_progress(settings, "choosing k for wknn_cv (leave-one-place-out)") as progress:
        methods, tuning = compared_methods(survey, settings.wifi, progress.advance)
    result = evaluate_methods(survey, tests, methods, settings.wifi.not_detected_dbm, settings.wifi.place_tolerance_m)
    for name, scores in result["methods"].items():
        typer.echo(
            f"{name:11s} mean {_metres(scores['mean_error_m'])}  unseen points {_metres(scores['unseen_points_mean_error_m'])}"
            f"  floor {'n/a' if scores['floor_accuracy'] is None else format(100 * scores['floor_accuracy'], '.2f') + ' %'}"
        )
    tuned = methods[-1]
    typer.echo(f"wknn_cv: k = {tuned.k} (leave-one-place-out error {tuning[tuned.k]:.2f} m)")
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        result["tuning"] = {"method": tuned.name, "k": tuned.k, "leave_one_place_out_error_m": {str(k): v for k, v in tuning.items()}}
        json_out.write_text(json.dumps(result, indent=1))


def _metres(value: float | None) -> str:
    return "n/a (no sample)" if value is None else f"{value:.2f} m"


def _settings(config: Path | None):
    from evp.config import load_settings

    return load_settings(config)
