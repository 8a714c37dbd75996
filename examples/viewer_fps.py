# Frames per second of a running `tadgs view` at 640x360: POST /api/frame in a loop, one
# request in flight, the camera (the viewer's home view scaled to 640 pixels wide) turning a
# little every frame as during a drag, PNG as the page asks. Python 3 standard library only.
#
#   cargo run --release -- view RUN --no-data --port 8766 &
#   python3 examples/viewer_fps.py http://127.0.0.1:8766 60
import json, math, sys, time, urllib.request
url = sys.argv[1].rstrip('/')
n = int(sys.argv[2]) if len(sys.argv) > 2 else 60
info = json.load(urllib.request.urlopen(url + '/api/info'))
home = info['home']
s = 640 / home['width']
cam = dict(home, width=640, height=int(round(home['height'] * s)), fx=home['fx'] * s, fy=home['fy'] * s, cx=home['cx'] * s, cy=home['cy'] * s)
print('size', cam['width'], cam['height'], 'gaussians', info['gaussians'])
R = [row[:3] for row in home['world_to_camera'][:3]]
t = [row[3] for row in home['world_to_camera'][:3]]
times = []
for i in range(n + 5):
    a = 0.002 * i  # yaw the camera about its own y axis
    c, s_ = math.cos(a), math.sin(a)
    Ry = [[c, 0, s_], [0, 1, 0], [-s_, 0, c]]
    Rn = [[sum(Ry[r][k] * R[k][col] for k in range(3)) for col in range(3)] for r in range(3)]
    tn = [sum(Ry[r][k] * t[k] for k in range(3)) for r in range(3)]
    cam['world_to_camera'] = [Rn[0] + [tn[0]], Rn[1] + [tn[1]], Rn[2] + [tn[2]], [0, 0, 0, 1]]
    body = json.dumps({'id': i, 'camera': cam, 'time': (i % 50) / 49.0, 'format': 'png'}).encode()
    req = urllib.request.Request(url + '/api/frame', data=body, headers={'Content-Type': 'application/json'})
    t0 = time.perf_counter(); data = urllib.request.urlopen(req).read(); dt = time.perf_counter() - t0
    if i >= 5: times.append(dt)
times.sort()
print(f'frames {len(times)}: {len(times)/sum(times):.1f} frames/s, median latency {1000*times[len(times)//2]:.1f} ms, p90 {1000*times[int(0.9*len(times))]:.1f} ms, png {len(data)} B')
