// Embree instances anchor, rays taken in dynamic chunks: the shared folder's
// anchors/embree_instances.cpp with one change, in the trace loop. There each of the THREADS
// threads traces a fixed share of the rays (nr * w / threads to nr * (w + 1) / threads); a
// frame's rays come lidar after lidar and beam after beam, so with one lidar the two halves are
// unequal work and the trace waits for the slower thread. Here every thread takes the next
// CHUNK rays from a std::atomic counter until none are left, as a C++ user would write it with
// tbb::parallel_for; the Embree calls, the scenes, the timed regions, the inputs and the outputs
// are the shared anchor's.
// Native Embree 3 anchor for a world of static geometry and moving rigid objects (instances):
// what a C++ user pays per frame when the world's tree is built once and only the objects move.
// Usage: embree_instances DIR THREADS
// DIR holds
//   static_vertices.f32 (V*3), static_faces.i32 (F*3)   the world, built once (medium quality)
//   object_vertices.f32, object_faces.i32                one mesh, built once, placed K times
//   transforms.f32 (FRAMES*K*12)                         each frame's K placements, 3x4 row-major
//   rays.f32 (FRAMES*N*8: ox oy oz dx dy dz tmin tmax)   each frame's rays
//   query.txt                                            closest | occluded
// Prints: static_build_ms, then per frame "commit_ms trace_ms" (the K new transforms and the
// top-level rebuild, then the rays on THREADS threads); writes t.f32 (FRAMES*N), as
// embree_native.cpp does (inf on a miss; 0 / inf for occluded / not).
#include <embree3/rtcore.h>
#include <chrono>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

template <class T> std::vector<T> load(const std::string& p) {
  std::ifstream f(p, std::ios::binary | std::ios::ate);
  size_t n = f.tellg(); f.seekg(0);
  std::vector<T> v(n / sizeof(T)); f.read((char*)v.data(), n); return v;
}
static const size_t CHUNK = 256;  // rays a thread takes at a time

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
  if (argc < 3) { fprintf(stderr, "usage: embree_instances DIR THREADS\n"); return 2; }
  std::string dir = argv[1]; int threads = atoi(argv[2]);
  auto SV = load<float>(dir + "/static_vertices.f32"); auto SF = load<int>(dir + "/static_faces.i32");
  auto OV = load<float>(dir + "/object_vertices.f32"); auto OF = load<int>(dir + "/object_faces.i32");
  auto X = load<float>(dir + "/transforms.f32"); auto R = load<float>(dir + "/rays.f32");
  std::string q; { std::ifstream f(dir + "/query.txt"); f >> q; }
  std::ifstream meta(dir + "/frames.txt"); size_t frames = 1, k = 0; meta >> frames >> k;
  size_t nr = R.size() / 8 / frames;
  RTCDevice dev = rtcNewDevice(("threads=" + std::to_string(threads)).c_str());

  double t0 = now();
  RTCScene top = rtcNewScene(dev);
  rtcSetSceneFlags(top, RTC_SCENE_FLAG_DYNAMIC);
  rtcSetSceneBuildQuality(top, RTC_BUILD_QUALITY_LOW);
  if (!SF.empty()) {
    RTCGeometry inst = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(inst, mesh_scene(dev, SV, SF));
    float id[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, id);
    rtcCommitGeometry(inst); rtcAttachGeometry(top, inst); rtcReleaseGeometry(inst);
  }
  RTCScene object = k ? mesh_scene(dev, OV, OF) : nullptr;
  std::vector<RTCGeometry> instances(k);
  for (size_t j = 0; j < k; j++) {
    instances[j] = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
    rtcSetGeometryInstancedScene(instances[j], object);
    rtcSetGeometryTransform(instances[j], 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, &X[j * 12]);
    rtcCommitGeometry(instances[j]); rtcAttachGeometry(top, instances[j]);
  }
  rtcCommitScene(top);
  printf("%.3f\n", now() - t0);

  std::vector<float> T(nr * frames);
  for (size_t f = 0; f < frames; f++) {
    double t1 = now();
    for (size_t j = 0; j < k; j++) {
      rtcSetGeometryTransform(instances[j], 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, &X[(f * k + j) * 12]);
      rtcCommitGeometry(instances[j]);
    }
    rtcCommitScene(top);
    double t2 = now();
    const float* rays = &R[f * nr * 8];
    float* out = &T[f * nr];
    std::vector<std::thread> pool;
    std::atomic<size_t> next{0};  // the first ray no thread has taken yet
    for (int w = 0; w < threads; w++) pool.emplace_back([&] {
      RTCIntersectContext ctx; rtcInitIntersectContext(&ctx);
      for (size_t lo; (lo = next.fetch_add(CHUNK)) < nr;)
      for (size_t i = lo, hi = lo + CHUNK < nr ? lo + CHUNK : nr; i < hi; i++) {
        const float* r = &rays[i * 8];
        RTCRayHit rh; RTCRay& ray = rh.ray;
        ray.org_x = r[0]; ray.org_y = r[1]; ray.org_z = r[2]; ray.dir_x = r[3]; ray.dir_y = r[4]; ray.dir_z = r[5];
        ray.tnear = r[6]; ray.tfar = r[7]; ray.mask = -1; ray.flags = 0; ray.time = 0;
        if (q == "occluded") { rtcOccluded1(top, &ctx, &ray); out[i] = ray.tfar < 0 ? 0.f : INFINITY; continue; }
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID; rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(top, &ctx, &rh); out[i] = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? INFINITY : ray.tfar;
      }
    });
    for (auto& t : pool) t.join();
    printf("%.3f %.3f\n", t2 - t1, now() - t2);
  }
  std::ofstream(dir + "/t.f32", std::ios::binary).write((char*)T.data(), T.size() * sizeof(float));
  return 0;
}
