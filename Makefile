# fogcast: `make run` serves http://127.0.0.1:8080, `make render` renders PNGs offline,
# `make bench` measures cost vs viewers (docs/performance.md), `make test` runs every test
# (installing lavapipe and Chromium first).
CARGO ?= cargo
SCENE ?= colonnade
ADDR ?= 127.0.0.1
PORT ?= 8080
# Extra `fogcast serve` flags, e.g. SERVE_ARGS="--config fogcast.toml --max-views 8".
SERVE_ARGS ?=

.PHONY: deps deps-runtime build run serve render bench checks test lint fmt clean

# Everything: the Vulkan driver (lavapipe) and Chromium for the browser test.
deps:
	@bash scripts/deps.sh all

# What running the server needs: the Vulkan driver only.
deps-runtime:
	@bash scripts/deps.sh runtime

build:
	$(CARGO) build --release

run: deps-runtime build serve

serve:
	./target/release/fogcast serve --scene $(SCENE) --addr $(ADDR) --port $(PORT) $(SERVE_ARGS)

render: deps-runtime build
	./target/release/fogcast render --scene $(SCENE) --viewers 4 --width 640 --height 360 --out out/$(SCENE)

# The default scaling sweep of docs/performance.md: 1-16 viewers along each scene's camera
# path, reference vs shared vs maps (the engines' shadow-map froxels) on the same frames,
# each also against the CPU truth on one image (colonnade at full size, ~6 s; Sponza and
# street at 80x45, ~10 s and ~65 s: truth costs pixels x segments x lights), at 320x180
# per viewer; colonnade also with 0.5 m and 0.125 m grids, the world media layer
# (`layer`) and the fixed-overlap scenario (paper Figure 12); smokehall for the smoke
# (issue 15: the shared smoke shadow maps once, the smoke per viewer). Reports and
# plots go to out/bench/<scene>/. About 45 minutes on 2 cores with lavapipe. The dev
# profile (opt-level 2, the one `make test` builds) is enough: the GPU work runs in Mesa.
# Flags for every run, e.g. BENCH_ARGS="--frames 3 --width 640 --height 360".
BENCH_ARGS ?=
FOGCAST_DEV := ./target/debug/fogcast
# `shared` runs with its defaults (demand-driven grid, temporal caching, shared surface
# shadow maps); `paper` is paper 000's method as published (frustum-gated grid traced
# every frame, surface shadow rays); `gated` is the paper's grid update with the maps
# (the same picture as `shared`) and `demand` adds the demand-driven update to it.
PAPER := --variant 'paper:demand=off,cache=off,shadow_map_px=0' --variant 'gated:demand=off,cache=off' --variant 'demand:cache=off'

bench: deps-runtime
	$(CARGO) build
	$(FOGCAST_DEV) bench --scene colonnade $(PAPER) --variant 'coarse:voxel_size_m=0.5' --variant 'fine:voxel_size_m=0.125' --variant 'layer:media_voxel_m=0.25' --overlap 10,25,50,75,100 --stereo 1,2,4,8 --truth 1 $(BENCH_ARGS)
	$(FOGCAST_DEV) bench --scene scenes/sponza.toml $(PAPER) --stereo 1,2,4,8 --truth 1 $(BENCH_ARGS)
	$(FOGCAST_DEV) bench --scene street --variant 'paper:demand=off,cache=off,shadow_map_px=0' $(BENCH_ARGS)
	$(FOGCAST_DEV) bench --scene smokehall --modes shared --time 14 $(BENCH_ARGS)

# The acceptance checks of issues 14 and 16 alone (colonnade and Sponza: reference,
# shared and maps at 1 and 16 viewers, one stereo session, the truth image), each
# scene's whole bench run CHECK_RUNS times: out/checks/<scene>/checks.md lists every
# check's value per run and how many runs pass its bound. A time ratio moves by 10-15 %
# between runs on lavapipe, so one run cannot tell a bound missed by a few percent from
# noise. About 20 minutes in all on 2 cores (a colonnade run ~1 min, a Sponza run ~3 min,
# most of it `truth` at 320×180, the bench's size, recomputed every run).
CHECK_RUNS ?= 5
checks: deps-runtime
	$(CARGO) build
	$(FOGCAST_DEV) bench --scene colonnade --viewers 1,16 --stereo 1 --truth 1 --repeat $(CHECK_RUNS) --out out/checks/colonnade $(BENCH_ARGS)
	$(FOGCAST_DEV) bench --scene scenes/sponza.toml --viewers 1,16 --stereo 1 --truth 1 --repeat $(CHECK_RUNS) --out out/checks/sponza $(BENCH_ARGS)

test: deps
	$(CARGO) test -- --test-threads=1

# Load test: `fogcast serve` on a free loopback port and the default `fogcast loadgen`
# sweep (1..16 viewers) against it, then the mixed-size sweep; reports in out/loadtest/
# and out/loadtest/mixed/ (docs/loadtest.md).
.PHONY: loadtest
loadtest: deps-runtime build
	@SCENE=$(SCENE) bash scripts/loadtest.sh

# Streaming soak (issue 17, not part of `make test`): codec quality (JPEG vs H.264 PSNR
# and bytes per frame), a throttled client among four, and a 10-minute churning soak
# against one `fogcast serve --debug-raw-frames`; reports in out/soak/ (docs/loadtest.md).
# About 20 minutes; SOAK_S, SOAK_THROTTLE_S, SOAK_QUALITY_S, ... shorten it.
.PHONY: soak
soak: deps-runtime build
	@SCENE=$(SCENE) bash scripts/soak.sh

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings

clean:
	$(CARGO) clean
	rm -rf out
