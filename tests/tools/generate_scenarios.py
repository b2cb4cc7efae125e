#!/usr/bin/env python3
"""Random soundmap-sim scenarios, for finding failures the built-in ones do not show.

    python3 tests/tools/generate_scenarios.py walkers FIRST END OUT_DIR
    python3 tests/tools/generate_scenarios.py several FIRST END OUT_DIR

`walkers`: one walking source (talker or white noise, 0.2-1.0 m/s, random
height 0.8-1.8 m, pauses), 2-3 robots started clustered or anywhere, active
positioning on, rooms 6-14 x 5-12 x 3 m at RT60 0.3-0.8 s, 40 s.
`several`: 2-3 sources (talkers, white noise, a fan; some walking, each on
for part of the run), 3 static robots (Pioneer, TurtleBot, ReSpeaker 6),
rooms 7-12 x 6-10 x 3 m at RT60 0.3-0.7 s, 30 s, `max_sources = 4`.

Scenario k is the same on every machine (Python's `random.Random`, seeded
1000 + k or 5000 + k). Run each with `soundmap-sim run OUT_DIR/NAME.toml`.
Nothing here is tuned to pass: the figures are in BENCHMARKS.md,
"Generated scenarios".
"""
import math
import os
import random
import sys


def preamble(name, description, duration_s, w, h, rt):
    """The scenario's name, its length and its shoebox room, then the noise table's first line."""
    return [f'name = "{name}"', f'description = "{description}"', f'duration_s = {duration_s}', 'seed = 1', '',
            '[room]', 'min_corner_m = [0.0, 0.0, 0.0]', f'size_m = [{w:.2f}, {h:.2f}, 3.0]', f'rt60_s = {rt}', '',
            '[noise]', 'sensor_snr_db = 30.0']


def walkers(k):
    r = random.Random(1000 + k)
    w, h = r.uniform(6, 14), r.uniform(5, 12)
    rt = round(r.uniform(0.3, 0.8), 2)
    nrob = r.choice([2, 2, 3])
    arrays = ['16soundsusb-pioneer', '16soundsusb-turtlebot', 'respeaker-6']
    talker = r.random() < 0.5
    speed = r.uniform(0.2, 1.0)
    rspeed = r.choice([0.5, 0.8, 0.8])
    s = [*preamble(f'gen{k}', f'generated walker {k}', 40.0, w, h, rt), 'reference_distance_m = 3.0', '',
         '[active_positioning]', 'enabled = true', 'theta_min_deg = 40.0', 'theta_max_deg = 140.0', '',
         '[coordinator.planner]', f'robot_speed_mps = {rspeed}', '',
         '[coordinator.server]', 'max_observation_rate_hz = 100000.0', '']
    cx, cy = r.uniform(1, w - 1), r.uniform(1, h - 1)
    for i in range(nrob):
        if r.random() < 0.5:
            x, y = cx + r.uniform(-0.8, 0.8), cy + r.uniform(-0.8, 0.8)
        else:
            x, y = r.uniform(0.7, w - 0.7), r.uniform(0.7, h - 0.7)
        x, y = min(max(x, 0.7), w - 0.7), min(max(y, 0.7), h - 0.7)
        array = arrays[i % len(arrays)] if nrob == 3 else arrays[i]
        s += ['[[robots]]', f'id = "r{i}"', f'array = "{array}"',
              f'start = [{x:.2f}, {y:.2f}, {r.uniform(-180, 180):.0f}.0]',
              f'max_speed_m_per_s = {rspeed}', 'max_turn_rate_deg_per_s = 120.0', '']
    signal = ('{ kind = "talker", low_hz = 300.0, high_hz = 3400.0, syllable_hz = 4.5 }' if talker
              else '{ kind = "white_noise" }')
    s += ['[[sources]]', f'signal = {signal}', 'rms = 0.1', 'path = [']
    t = 0.0
    x, y = r.uniform(1, w - 1), r.uniform(1, h - 1)
    z = round(r.uniform(0.8, 1.8), 2)
    s.append(f'  {{ t_s = 0.0, x_m = {x:.2f}, y_m = {y:.2f}, z_m = {z} }},')
    while t < 40:
        if r.random() < 0.2:
            t += r.uniform(1, 4)
        else:
            nx, ny = r.uniform(1, w - 1), r.uniform(1, h - 1)
            t += math.hypot(nx - x, ny - y) / speed
            x, y = nx, ny
        s.append(f'  {{ t_s = {t:.2f}, x_m = {x:.2f}, y_m = {y:.2f}, z_m = {z} }},')
    s.append(']')
    return f'gen{k}', '\n'.join(s) + '\n'


def several(k):
    r = random.Random(5000 + k)
    w, h = r.uniform(7, 12), r.uniform(6, 10)
    rt = round(r.uniform(0.3, 0.7), 2)
    nsrc = r.choice([2, 2, 3])
    s = [*preamble(f'mgen{k}', f'generated several sources {k}', 30.0, w, h, rt), 'reference_distance_m = 2.0', '',
         '[coordinator.sources]', 'max_sources = 4', '']
    arrays = ['16soundsusb-pioneer', '16soundsusb-turtlebot', 'respeaker-6']
    for i in range(3):
        x, y = r.uniform(0.8, w - 0.8), r.uniform(0.8, h - 0.8)
        s += ['[[robots]]', f'id = "r{i}"', f'array = "{arrays[i]}"',
              f'start = [{x:.2f}, {y:.2f}, {r.uniform(-180, 180):.0f}.0]', '']
    for _ in range(nsrc):
        kind = r.choice(['talker', 'talker', 'white', 'fan'])
        if kind == 'talker':
            lo, hi = r.choice([300, 400]), r.choice([3400, 4000])
            signal = f'{{ kind = "talker", low_hz = {lo}.0, high_hz = {hi}.0, syllable_hz = {r.uniform(4, 6):.1f} }}'
            rms = 0.1
        elif kind == 'white':
            signal, rms = '{ kind = "white_noise" }', 0.05
        else:
            signal, rms = '{ kind = "fan", hum_hz = 120.0 }', 0.02
        z = round(r.uniform(0.6, 1.8), 2)
        x, y = r.uniform(1, w - 1), r.uniform(1, h - 1)
        path = [f'{{ t_s = 0.0, x_m = {x:.2f}, y_m = {y:.2f}, z_m = {z} }}']
        if kind == 'talker' and r.random() < 0.5:
            x2, y2 = r.uniform(1, w - 1), r.uniform(1, h - 1)
            path.append(f'{{ t_s = 30.0, x_m = {x2:.2f}, y_m = {y2:.2f}, z_m = {z} }}')
        a, b = r.uniform(0, 8), r.uniform(18, 30)
        s += ['[[sources]]', f'signal = {signal}', f'rms = {rms}', 'path = [' + ', '.join(path) + ']',
              f'active = [[{a:.1f}, {b:.1f}]]', '']
    return f'mgen{k}', '\n'.join(s)


def main():
    if len(sys.argv) != 5 or sys.argv[1] not in ('walkers', 'several'):
        sys.exit(__doc__)
    make = walkers if sys.argv[1] == 'walkers' else several
    first, end, out = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    os.makedirs(out, exist_ok=True)
    for k in range(first, end):
        name, text = make(k)
        with open(os.path.join(out, f'{name}.toml'), 'w') as f:
            f.write(text)


if __name__ == '__main__':
    main()
