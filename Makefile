# fogcast: `make run` renders, `make test` runs every test (installing lavapipe first).
CARGO ?= cargo
SCENE ?= colonnade

.PHONY: deps build run test lint fmt clean

deps:
	@bash scripts/deps.sh

build:
	$(CARGO) build --release

run: deps build
	./target/release/fogcast render --scene $(SCENE) --viewers 4 --width 640 --height 360 --out out/$(SCENE)

test: deps
	$(CARGO) test -- --test-threads=1

lint:
	$(CARGO) fmt --check
	$(CARGO) clippy --all-targets -- -D warnings

clean:
	$(CARGO) clean
	rm -rf out
