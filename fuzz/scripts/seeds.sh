#!/usr/bin/env bash
# Rebuilds the seed corpora fuzz/corpus/<target>/ from the real data ($PFSLAM_DATA, default
# ../shared/data) and the simulator, cut to a few KB each: the fuzzer mutates structure, and
# big seeds only slow it down. Usage: fuzz/scripts/seeds.sh
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
data="${PFSLAM_DATA:-$root/../shared/data}"
out="$root/fuzz/corpus"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
cd "$root"
cargo build --release -q -p pfslam-cli --bin pfslam
cargo build --release -q -p pfslam-fuzz-harness --example mcap_seed
bin="${CARGO_TARGET_DIR:-$root/target}/release"
mk() { rm -rf "${out:?}/$1"; mkdir -p "$out/$1"; }

# head closes its pipe early: the writer's SIGPIPE is expected there
set +o pipefail

mk carmen
head -n 4 "$data/freiburg/mit-csail/mit-csail.clf" > "$out/carmen/mit-csail.clf"
for f in intel orebro seattle acapulco; do
  zcat "$data/carmen/$f-corrected.log.gz" | grep -v '^#' | head -c 6000 | head -n -1 > "$out/carmen/$f.log"
done
# PARAM and comment lines, then an ODOM and a laser line, gzipped
zcat "$data/carmen/intel-corrected.log.gz" | head -n 40 | head -c 3000 | head -n -1 \
  | gzip -9 > "$out/carmen/intel-head.log.gz"

mk ros1_bag
python3 fuzz/scripts/small_bag.py "$data/freiburg/mit-csail/mit-csail.bag" "$out/ros1_bag/mit-none.bag" 1 none
python3 fuzz/scripts/small_bag.py "$data/freiburg/mit-csail/mit-csail.bag" "$out/ros1_bag/mit-bz2.bag" 1 bz2
python3 fuzz/scripts/small_bag.py "$data/freiburg/intel/intel.bag" "$out/ros1_bag/intel-bz2.bag" 1 bz2

mk mcap
"$bin/examples/mcap_seed" "$out/ros1_bag/mit-none.bag" "$out/mcap/mit.mcap"
"$bin/examples/mcap_seed" "$out/ros1_bag/intel-bz2.bag" "$out/mcap/intel.mcap"

"$bin/pfslam" simulate --duration-s 0.2 --stereo-rate-hz 0 --out "$tmp/car" --log warn
"$bin/pfslam" simulate --vehicle humanoid --duration-s 0.5 --out "$tmp/hum" --log warn
mk ucsd_encoder
head -n 8 "$tmp/car/sensor_data/encoder.csv" > "$out/ucsd_encoder/sim.csv"
mk ucsd_fog
head -n 8 "$tmp/car/sensor_data/fog.csv" > "$out/ucsd_fog/sim.csv"
mk ucsd_lidar
# the first byte picks the beam count: 0 -> the car's 286
{ printf '\0'; head -n 2 "$tmp/car/sensor_data/lidar.csv"; } > "$out/ucsd_lidar/sim.csv"
mk ucsd_calib
for f in EncoderParameter Vehicle2FOG Vehicle2Lidar Vehicle2Stereo lidar_param stereo_param; do
  cp "$data/ucsd/param/$f.txt" "$out/ucsd_calib/$f.txt"
done
mk opencv_yaml
cp "$data/ucsd/param/left_camera.yaml" "$data/ucsd/param/right_camera.yaml" "$out/opencv_yaml/"

mk humanoid
{ cat "$tmp/hum/calibration.txt"; printf '\0'; head -n 4 "$tmp/hum/odometry.csv"; printf '\0'
  head -n 4 "$tmp/hum/imu.csv"; printf '\0'; head -n 4 "$tmp/hum/joints.csv"; printf '\0'
  head -n 2 "$tmp/hum/lidar.csv"; } > "$out/humanoid/sim.bin"

mk tum
head -n 6 "$tmp/car/ground_truth.tum" > "$out/tum/sim.tum"
printf '# stamp x y z qx qy qz qw\n1.5 1 2 0 0 0 0.7071068 0.7071068\n1.6e0 1 2 0 0 0 0 -1\n' > "$out/tum/hand.tum"

mk relations
for f in intel aces mit-csail; do head -n 12 "$data/freiburg/$f/$f.relations" > "$out/relations/$f.relations"; done

mk map_server
yaml='image: map.pgm\nresolution: 0.05\norigin: [-0.4, -0.3, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n'
{ printf "$yaml"; printf '\0'; printf 'P5\n# made by hand\n8 6\n255\n'
  for _ in 1 2 3 4 5 6; do printf '\376\376\0\0\315\315\376\0'; done; } > "$out/map_server/p5.bin"
{ printf "${yaml/trinary/scale}"; printf '\0'; printf 'P2\n4 3\n255\n254 0 205 254\n0 0 0 254\n205 205 254 0\n'; } \
  > "$out/map_server/p2.bin"

mk npy
python3 - "$out/npy/small.npy" <<'PY'
import struct, sys
header = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"
header += " " * (63 - (10 + len(header)) % 64) + "\n"
body = struct.pack("<6f", 0.0, -1.5, 2.0, 0.25, 3.0, -4.0)
open(sys.argv[1], "wb").write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + body)
PY

mk config_toml
"$bin/pfslam" print-config | grep -v '^#' > "$out/config_toml/default.toml"
cp "$tmp/car/sim.toml" "$out/config_toml/sim-car.toml"
printf '[filter]\nparticles = 30\n\n[input]\nscan_topic = "/scan"\n' > "$out/config_toml/small.toml"

du -sh "$out"; find "$out" -type f | wc -l
