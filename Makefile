# Common commands; see README.md.
PY ?= python

.PHONY: install test test-integration test-all lint format typecheck check bench bench-peak bench-compile bench-parts bench-lm bench-grid bench-grid-fit bench-faults bench-diagnose bench-unforeseen bench-fresh \
	bench-coverage bench-manoeuvres manoeuvres data sweep \
	smoke ui diagnose

install:  ## install the project and its development tools
	$(PY) -m pip install -e ".[dev]"

test:  ## the fast tier: every test but the integration and slow ones (under 6 min on 2 cores)
	$(PY) -m pytest -m "not integration and not slow"

test-integration:  ## the integration tier: Ray clusters, the browser, planted end-to-end diagnoses, heavy compilation
	$(PY) -m pytest -m "integration and not slow"

test-all:  ## both tiers and the slow tests (identification runs)
	$(PY) -m pytest -m "slow or not slow"

lint:
	ruff check src tests benchmarks
	ruff format --check src tests benchmarks

format:
	ruff format src tests benchmarks
	ruff check --fix src tests benchmarks

typecheck:
	mypy

check: lint typecheck  ## what CI runs: lint, types and both test tiers (the README's test command)
	$(PY) -m pytest

bench:  ## simulator throughput (traj-steps/s) for B = 20, 540, 19440
	$(PY) benchmarks/throughput.py

bench-peak:  ## simulate and moments throughput as a fraction of ../shared/tools/fma_peak.py
	PYTHONPATH=. $(PY) benchmarks/peak_fraction.py

bench-compile:  ## seconds to compile the base model's and two effects' kernels in one process, empty cache (2-5 min)
	$(PY) benchmarks/compile_time.py

bench-parts:  ## the objective kernel's time by part of the right-hand side (each left out in turn; 10 min)
	PYTHONPATH=. $(PY) benchmarks/kernel_parts.py

bench-lm:  ## a Levenberg-Marquardt Jacobian batch: residuals vs the simulator alone
	PYTHONPATH=. $(PY) benchmarks/lm_residuals.py

bench-grid:  ## the paper's 27-job grid at 3,000 evaluations per job: wall time, implied 100,000
	$(PY) benchmarks/sweep_grid.py --evaluations 3000

bench-grid-fit:  ## the grid at 3,000 and 30,000 evaluations per job, a fixed + per-evaluation line to 100,000 (25 min on 2 cores)
	$(PY) benchmarks/sweep_grid.py --evaluations 3000,30000

bench-faults:  ## what each fault the sweep survives costs: jobs lost or run twice, results, wall time (6 min)
	PYTHONPATH=. $(PY) benchmarks/faults.py --out benchmarks/out/faults.json

bench-diagnose:  ## planted-effect benchmark of the diagnosis (36 cases: catalog, unlisted forms, none; 1-2 h on 2 cores)
	PYTHONPATH=. $(PY) benchmarks/diagnose_planted.py --out benchmarks/out/diagnose

bench-unforeseen:  ## the diagnosis on planted forms no library term expresses (39 cases, strong, weak and medium, each with what its planted form itself reaches; hours on 2 cores)
	PYTHONPATH=. $(PY) benchmarks/diagnose_planted.py --set unforeseen --reach --out benchmarks/out/diagnose

bench-fresh:  ## the diagnosis on the fresh forms, written after the method was tuned (16 cases, strong and medium; 40 min on 2 cores)
	PYTHONPATH=. $(PY) benchmarks/diagnose_planted.py --set fresh --reach --out benchmarks/out/diagnose

bench-coverage:  ## how often the parameters' 90 % intervals hold known truths (simulated data; 8 min on 2 cores)
	PYTHONPATH=. $(PY) benchmarks/interval_coverage.py

bench-manoeuvres:  ## wall time of one model's manoeuvres with 50 parameter samples on one core
	NUMBA_NUM_THREADS=1 PYTHONPATH=. $(PY) benchmarks/manoeuvres.py --time

manoeuvres:  ## the manoeuvre tables and figures of the docs: EFD and the shipped model with its intervals
	PYTHONPATH=. $(PY) benchmarks/manoeuvres.py --docs docs/manoeuvres

diagnose:  ## missing physics on the real recordings: best shipped model, Train-R, paper's test set
	$(PY) -m sweep.diagnose --params results/best_params.json --train R --test paper \
		--out docs/diagnosis-real

data:  ## download the FRT-DS-ESSO recordings into $$MMG_DATA_DIR (or the user cache)
	$(PY) -m sweep.download

sweep:  ## the paper's grid: 3 objectives x 3 training sets x 3 seeds (default budget: short)
	$(PY) -m sweep -m objective=J1,J2,J3 train=R,TR,TZR seed=0,1,2

smoke:  ## a two-job sweep at budget=smoke
	$(PY) -m sweep -m objective=J1,J2 train=R seed=0 budget=smoke sweep.name=smoke

ui:  ## the MLflow UI on 127.0.0.1:5000 for ./mlflow.db, opened on the sweep's runs table
	$(PY) -m sweep.ui --tracking-uri sqlite:///$(CURDIR)/mlflow.db --port 5000

.PHONY: docs
docs:  ## the documentation site (MkDocs, strict) into build/site
	$(PY) -m mkdocs build --strict --site-dir build/site
