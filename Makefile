.PHONY: install test bench experiments
install:
	pip install -e ".[test]"
test:
	pytest -q -n 2
# bsslam bench runs the logs of $BSSLAM_DATA (e.g. BSSLAM_DATA=../shared/data make bench)
bench:
	@if [ -n "$$BSSLAM_DATA" ]; then bsslam bench; else echo "bsslam bench skipped: set BSSLAM_DATA to a folder of logs"; fi
	python benchmarks/bench_spline.py
	python benchmarks/bench_segment.py
	python benchmarks/bench_filter.py
	python benchmarks/bench_filter.py --defaults
	python benchmarks/corridor_consistency.py
experiments:
	bsslam experiment fit-knots --out results/fit-knots
	bsslam experiment fit-order --out results/fit-order
	bsslam experiment consistency --variant no-extension --out results/consistency-no-extension
	bsslam experiment consistency --variant inflated-r --out results/consistency-inflated-r
	bsslam experiment consistency --variant extension --out results/consistency-extension
	bsslam experiment heading-gain --out results/heading-gain
