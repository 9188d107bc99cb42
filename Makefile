# Every target creates or refreshes the virtual environment in .venv first (idempotent).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: venv test test-data lint demo demo-video bench bench-node clean

# The demo's bag; extra pearl_node parameters (e.g. DEMO_ARGS='-p label_cost:=300.0'), which
# pearl_replay gets too (as --set label_cost=300.0); pearl_play's rate (Hz, 0 = as fast as the
# node answers).
DEMO_BAG ?= bags/1R2RCR_g12
DEMO_ARGS ?=
DEMO_RATE ?= 10
DEMO_SET = $(foreach arg,$(DEMO_ARGS),$(if $(findstring :=,$(arg)),--set $(subst :=,=,$(arg))))
# Where make demo writes the output bag (the same online code as the node, on the same bag).
DEMO_OUT ?= build/demo_labels
# ROS 2 discovery stays on this machine for the demo and the node benchmark.
ROS_ENV := ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

venv: $(STAMP)

# Reinstalled only when the requirements or setup files change.
$(STAMP): requirements.txt requirements-dev.txt setup.py setup.cfg
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -r requirements-dev.txt
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

# The suite that needs nothing beside the clone: synthetic scenes and the bundled bags.
test: venv
	$(BIN)/python -m pytest -q test -m 'not data'

# Tests on whole datasets (Hopkins155, ...) under $$PEARL_DATA, default ../shared/data; they fail,
# with one line saying where the data is expected, when it is missing.
test-data: venv
	$(BIN)/python -m pytest -q test -m data

# ruff on everything; mypy --strict on the ROS-free layers, mypy on the whole package. Every
# check runs; the target fails if any failed.
lint: venv
	status=0; \
	$(BIN)/ruff check . || status=1; \
	$(BIN)/mypy --strict pearl_ros/core pearl_ros/online || status=1; \
	$(BIN)/mypy pearl_ros || status=1; \
	exit $$status

# pearl_node in the background, told the bag's feature message type (pearl_play --msg-type);
# the bag's feature messages played into it live by pearl_play (labels and accuracy printed per
# frame), then Ctrl-C to the node; then pearl_replay writes the output bag of the same bag with
# the same parameters to $(DEMO_OUT), and pearl_score scores it and says how to read it.
demo: venv
	@type=$$($(BIN)/pearl_play $(DEMO_BAG) --msg-type) || exit 1; \
	$(ROS_ENV) $(BIN)/pearl_node --ros-args -r features:=/feature_tracker/feature \
	    --params-file config/pearl.yaml -p msg_type:=$$type $(DEMO_ARGS) & node=$$!; \
	$(ROS_ENV) $(BIN)/pearl_play $(DEMO_BAG) --timeout 20 --rate $(DEMO_RATE); status=$$?; \
	kill -INT $$node; wait $$node; \
	test $$status -eq 0 || exit $$status; \
	echo; echo "pearl_replay: the same bag, code and parameters, offline, into $(DEMO_OUT)"; \
	mkdir -p $(dir $(DEMO_OUT)) && \
	$(BIN)/pearl_replay $(DEMO_BAG) --output $(DEMO_OUT) --params config/pearl.yaml \
	    $(DEMO_SET) --force && \
	echo && $(BIN)/pearl_score $(DEMO_OUT) --summary --explain

# A rendered clip (render_scene: a panning, zooming camera; one object moving in view, one crossing
# it) through pearl_video: build/demo_clip.mp4 (the clip), build/demo_video_labels (the bag),
# build/demo_labels.mp4 (the clip with the labels drawn) and build/demo_still.png (its frame
# DEMO_STILL, the README's picture).
DEMO_SEED ?= 0
DEMO_STILL ?= 45
demo-video: venv
	mkdir -p build
	$(BIN)/python -c "import cv2; from pearl_ros.tracking.render import render_scene; \
	scene = render_scene($(DEMO_SEED), frames=60, size=(480, 640)); \
	out = cv2.VideoWriter('build/demo_clip.mp4', cv2.VideoWriter.fourcc(*'mp4v'), 30, (640, 480)); \
	[out.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)) for frame in scene.frames]; out.release()"
	$(BIN)/pearl_video build/demo_clip.mp4 --output-bag build/demo_video_labels \
	    --annotated build/demo_labels.mp4 --force
	$(BIN)/python -c "import cv2, sys; video = cv2.VideoCapture('build/demo_labels.mp4'); \
	video.set(cv2.CAP_PROP_POS_FRAMES, $(DEMO_STILL)); ok, frame = video.read(); \
	sys.exit(not (ok and cv2.imwrite('build/demo_still.png', frame)))"
	@echo "wrote build/demo_labels.mp4 and build/demo_still.png (frame $(DEMO_STILL))"

bench: venv
	$(BIN)/pearl_bench hopkins155 ../shared/data/hopkins155 --frames all

# End-to-end latency of pearl_node and of a no-op baseline node (in-process): 300, 500 and
# 1000 features at 30 Hz, 2000 at 10 Hz, window 10 (issue 17).
bench-node: venv
	$(ROS_ENV) $(BIN)/pearl_node_bench --features 300 500 1000 2000@10 --rate 30 --frames 300 \
		--set window=10

clean:
	rm -rf $(VENV) build *.egg-info
