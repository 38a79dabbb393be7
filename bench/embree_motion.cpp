// Native Embree 3 with motion blur: a static world and rigid objects (instances) that move during
// the frame, each ray traced at its own time. The idea of ../shared/anchors/embree_instances.cpp
// (the world's tree built once; per frame only the instances' transforms and a top-level commit),
// with two time steps per instance (rtcSetGeometryTimeStepCount(inst, 2), the placement at the
// frame's start and end) and RTCRayHit.ray.time set from each ray.
//
// Build (bench/motion.py does this on first use, into ~/.cache/dacrt-bench):
//   g++ -O3 -march=native -std=c++17 embree_motion.cpp -o embree_motion -lembree3 -lpthread
// Usage: embree_motion DIR THREADS MODE
//   MODE static   one time step per instance (its start placement), every ray at time 0
//   MODE moving   two time steps per instance (start, end), each ray at its own time in [0, 1]
// DIR holds
//   static_vertices.f32 (V*3), static_faces.i32 (F*3)   the world, built once (medium quality)
//   object_vertices.f32, object_faces.i32                one mesh, built once, placed K times
//   transforms.f32 (FRAMES*K*2*12)                       each frame's K placements at the start
//                                                        and the end, 3x4 row-major each
//   rays.f32 (N*9: ox oy oz dx dy dz tmin tmax time)     the rays, the same every frame
//   frames.txt                                           "FRAMES K"
// Prints: the one-time build ms (world, object, first top level), then per frame "commit_ms
// trace_ms" (the K instances' transforms and the top-level rebuild, then the rays on THREADS
// threads: Embree's own device threads for the commit, THREADS std::threads for rtcIntersect1).
// Writes the last frame's hits: t.f32 (N, inf on a miss), inst.i32 (N: the top level's geomID,
// 0 for the world, 1 + j for object j; -1 on a miss), prim.i32 (N: the triangle's row; -1 on a
// miss).
#include <embree3/rtcore.h>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

template <class T> std::vector<T> load(const std::string& p) {
  std::ifstream f(p, std::ios::binary | std::ios::ate);
  if (!f) { fprintf(stderr, "cannot read %s\n", p.c_str()); exit(1); }
  size_t n = f.tellg(); f.seekg(0);
  std::vector<T> v(n / sizeof(T)); f.read((char*)v.data(), n); return v;
}
template <class T> void save(const std::string& p, const std::vector<T>& v) {
  std::ofstream(p, std::ios::binary).write((const char*)v.data(), v.size() * sizeof(T));
}
static double now() { return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

static RTCScene mesh_scene(RTCDevice dev, const std::vector<float>& V, const std::vector<int>& F) {
  RTCScene s = rtcNewScene(dev);
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  memcpy(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 12, V.size() / 3), V.data(), V.size() * 4);
  memcpy(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 12, F.size() / 3), F.data(), F.size() * 4);
  rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_MEDIUM);
  rtcCommitGeometry(g); rtcAttachGeometry(s, g); rtcReleaseGeometry(g);
  rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_MEDIUM);
  rtcCommitScene(s);
  return s;
}

int main(int argc, char** argv) {
  if (argc < 4) { fprintf(stderr, "usage: embree_motion DIR THREADS static|moving\n"); return 2; }
  std::string dir = argv[1]; int threads = atoi(argv[2]); std::string mode = argv[3];
  if (mode != "static" && mode != "moving") { fprintf(stderr, "MODE: static or moving\n"); return 2; }
  const bool moving = mode == "moving";
  auto SV = load<float>(dir + "/static_vertices.f32"); auto SF = load<int>(dir + "/static_faces.i32");
  auto OV = load<float>(dir + "/object_vertices.f32"); auto OF = load<int>(dir + "/object_faces.i32");
  auto X = load<float>(dir + "/transforms.f32"); auto R = load<float>(dir + "/rays.f32");
  std::ifstream meta(dir + "/frames.txt"); size_t frames = 1, k = 0; meta >> frames >> k;
  size_t nr = R.size() / 9;
  RTCDevice dev = rtcNewDevice(("threads=" + std::to_string(threads)).c_str());
  // frame f, object j, step s (0: start, 1: end): its 3x4 row-major placement
  auto placement = [&](size_t f, size_t j, unsigned s) { return &X[((f * k + j) * 2 + s) * 12]; };
  auto place = [&](RTCGeometry inst, size_t f, size_t j) {
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, placement(f, j, 0));
    if (moving) rtcSetGeometryTransform(inst, 1, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, placement(f, j, 1));
    rtcCommitGeometry(inst);
  };

  double t0 = now();
  RTCScene top = rtcNewScene(dev);
  rtcSetSceneFlags(top, RTC_SCENE_FLAG_DYNAMIC);
  rtcSetSceneBuildQuality(top, RTC_BUILD_QUALITY_LOW);
  {
    // the world is geomID 0 of the top level, as mesh 0 is the engine's
    RTCGeometry inst = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, mesh_scene(dev, SV, SF));
    float id[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, id);
    rtcCommitGeometry(inst); rtcAttachGeometryByID(top, inst, 0); rtcReleaseGeometry(inst);
  }
  RTCScene object = k ? mesh_scene(dev, OV, OF) : nullptr;
  std::vector<RTCGeometry> instances(k);
  for (size_t j = 0; j < k; j++) {
    instances[j] = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instances[j], object);
    // two time steps over the default time range [0, 1]: Embree interpolates the matrices linearly
    if (moving) rtcSetGeometryTimeStepCount(instances[j], 2);
    place(instances[j], 0, j);
    rtcAttachGeometryByID(top, instances[j], 1 + j);
  }
  rtcCommitScene(top);
  printf("%.3f\n", now() - t0);
  if (rtcGetDeviceError(dev) != RTC_ERROR_NONE) { fprintf(stderr, "Embree error while building\n"); return 1; }

  std::vector<float> T(nr); std::vector<int> I(nr), P(nr);
  for (size_t f = 0; f < frames; f++) {
    double t1 = now();
    for (size_t j = 0; j < k; j++) place(instances[j], f, j);
    rtcCommitScene(top);
    double t2 = now();
    std::vector<std::thread> pool;
    for (int w = 0; w < threads; w++) pool.emplace_back([&, w] {
      RTCIntersectContext ctx; rtcInitIntersectContext(&ctx);
      size_t lo = nr * w / threads, hi = nr * (w + 1) / threads;
      for (size_t i = lo; i < hi; i++) {
        const float* r = &R[i * 9];
        RTCRayHit rh; RTCRay& ray = rh.ray;
        ray.org_x = r[0]; ray.org_y = r[1]; ray.org_z = r[2]; ray.dir_x = r[3]; ray.dir_y = r[4]; ray.dir_z = r[5];
        ray.tnear = r[6]; ray.tfar = r[7]; ray.mask = -1; ray.flags = 0; ray.id = 0;
        ray.time = moving ? r[8] : 0.f;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID; rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(top, &ctx, &rh);
        bool hit = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        T[i] = hit ? ray.tfar : INFINITY;
        I[i] = hit ? (int)rh.hit.instID[0] : -1;
        P[i] = hit ? (int)rh.hit.primID : -1;
      }
    });
    for (auto& t : pool) t.join();
    printf("%.3f %.3f\n", t2 - t1, now() - t2);
  }
  if (rtcGetDeviceError(dev) != RTC_ERROR_NONE) { fprintf(stderr, "Embree error while tracing\n"); return 1; }
  save(dir + "/t.f32", T); save(dir + "/inst.i32", I); save(dir + "/prim.i32", P);
  return 0;
}
