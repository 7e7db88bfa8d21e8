"""Compensating the Aye piezo with the model `piest fit` keeps by default.

The model is fitted on the identification run (`pj.identify`, the defaults of `piest fit`, and
`model="pi"` beside it), then inverted for the output the actuator produced on the validation
run. A model that describes the actuator gives back the input that was applied; a model whose
inverse drifts asks for inputs the actuator was never driven with.

Writes experiments/results/compensate_real_data.json.
Run: python experiments/compensate_real_data.py
"""

import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def compensate(model, val) -> dict:
    """The feedforward for the validation run's measured output, against its measured input."""
    u = np.asarray(pj.feedforward(model, val.y))
    e = u - np.asarray(val.u)
    return {
        "u_min": float(u.min()),
        "u_max": float(u.max()),
        "rms_input_error": float(np.sqrt(np.mean(e**2))),
        "inverse_problem": model.inverse_problem(),
    }


def summary(result, seconds) -> dict:
    d = result.to_json()
    return {
        "structure": d["structure"],
        "n_plays": d["n_plays"],
        "creep": d.get("creep"),
        "validation_rmse": d["validation_rmse"],
        "validation_rmse_ic": d["validation_rmse_ic"],
        "seconds": seconds,
    }


def main() -> None:
    ident = pj.load_dataset("piezo_aye2018_identification")
    val = pj.load_dataset("piezo_aye2018_validation")
    out = {"measured_input_range": [float(val.u.min()), float(val.u.max())]}
    for name, options in (("default", {}), ("pi", {"model": "pi"})):
        start = time.perf_counter()
        result = pj.identify(ident, val, **options)
        seconds = time.perf_counter() - start
        model = result.fit.model()
        out[name] = summary(result, seconds) | compensate(model, val)
        print(name, out[name], flush=True)
    pj.write_json(RESULTS / "compensate_real_data.json", out)


if __name__ == "__main__":
    main()
