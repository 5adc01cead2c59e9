# The two Quick-start commands (README): `make demo` and `make test`.
# Each creates .venv with the project's own dependencies, so a fresh machine needs only
# Python >= 3.11, pip and git.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test bench install clean firmware

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test,plots,firmware]"
	touch $@

install: $(BIN)/.installed

# A second `make demo` continues the run in demo-results/ (or writes its finished results
# again from the checkpoint) instead of being refused as a reused folder.
demo: install
	@if [ -f demo-results/checkpoint/run.json ]; then \
		echo "continuing the demo in demo-results/ (--resume)"; $(BIN)/snan-hil demo --resume; \
	else $(BIN)/snan-hil demo; fi

# The MIK32 firmware ELF (build/firmware/snan-fw.elf), built with the pip-installed Zig
# toolchain; rebuilt when a source or the generator changes, or any Python file the constants
# header is generated from: build.py writes those to build/firmware/snan-fw.d (derived from the
# generator's imports, never listed by hand). The emulator refuses an ELF whose embedded
# constants hash does not match the Python definitions (stale).
FW_ELF  := build/firmware/snan-fw.elf
FW_DEPS := $(wildcard firmware/src/*) firmware/link.ld firmware/build.py firmware/gen_constants.py

$(FW_ELF): $(BIN)/.installed $(FW_DEPS)
	$(BIN)/python firmware/build.py

-include build/firmware/snan-fw.d

# The native peripheral core of the emulator's instruction-level MCU (a host shared library,
# same toolchain); without it the emulator falls back to the slow Python reference core.
NATIVE_LIB  := build/firmware/libmik32periph.so
NATIVE_DEPS := firmware_emu/native/mik32_periph.c firmware_emu/native/build.py \
               firmware_emu/mik32_state.py

$(NATIVE_LIB): $(BIN)/.installed $(NATIVE_DEPS)
	$(BIN)/python firmware_emu/native/build.py

firmware: $(FW_ELF) $(NATIVE_LIB)

test: install firmware
	$(BIN)/python -m pytest -n 2

bench: install firmware
	$(BIN)/python bench/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info
