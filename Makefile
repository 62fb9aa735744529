# The two README commands: `make demo` and `make test`. Both set everything up first.
export PATH := $(HOME)/.cargo/bin:$(PATH)
.PHONY: setup demo test test-rust test-python bench lint

setup:
	bash scripts/setup.sh

demo: setup
	.venv/bin/pointrig demo

test: setup test-rust test-python

# the release profile of the extension's build, so its compiled dependencies are reused
test-rust:
	cargo test --no-default-features --release -- --quiet

test-python:
	.venv/bin/python -m pytest -q

bench: setup
	.venv/bin/python -m benchmarks.run_all

lint:
	bash scripts/setup.sh --python-only
	cargo fmt --check && cargo clippy --all-targets -- -D warnings
	.venv/bin/ruff check python tests benchmarks scripts
