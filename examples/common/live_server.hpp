#pragma once
// `--serve ADDR:PORT`: a live view of a run in a browser. One thread serves a self-contained page
// (inline HTML and JavaScript, nothing fetched from elsewhere) that polls /state.json and
// /render.bmp. The mapping loop hands over a snapshot after each frame with publish(), which never
// waits: when the server is copying the previous one, the new one is dropped. Hostile or slow
// clients cost the loop nothing: sockets are non-blocking, connections are capped, every
// connection has a deadline and one request (HTTP/1.0, Connection: close), requests are bounded.

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace octofuse::examples {

constexpr int kLiveHistoryFrames = 120;      // stage times plotted
constexpr int kLiveTrajectoryPoints = 4096;  // camera positions kept (every k-th when longer)

struct LiveSnapshot {
  long frame = 0;  // frames processed so far
  double fps = 0.0;
  std::string tracking;  // "tracked", "lost", ...
  std::uint64_t map_bytes_used = 0;
  std::uint64_t map_bytes_reserved = 0;
  std::uint32_t blocks_used = 0;
  std::uint32_t block_capacity = 0;
  // Per frame, oldest first: pre-process, track, integrate, ray-cast (ms), 4 floats a frame.
  std::vector<float> stage_ms;
  std::vector<float> trajectory_p_W;  // x, y, z a camera position, oldest first
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgb;  // the last ray-cast shaded by scale, rows top first
  // With a distance field (--esdf): a horizontal slice of it at the camera's height
  // (esdf_slice.hpp), rows top first; slice_width 0: none.
  int slice_width = 0;
  int slice_height = 0;
  float slice_z_m = 0.0f;
  float slice_max_m = 0.0f;         // the distance shown blue
  std::uint64_t slice_version = 0;  // map version of the field the slice shows
  std::vector<std::uint8_t> slice_rgb;
};

struct LiveServerLimits {
  int max_connections = 32;  // beyond this, new connections are closed at once
  int timeout_ms = 5000;     // a connection's whole life: read the request, send the answer
  std::size_t max_request_bytes = 8192;
};

// Splits --serve's PORT, ADDR:PORT or [ADDR]:PORT (a numeric address; localhost is 127.0.0.1)
// into host and port; false with a one-line reason in *error when it is malformed. Checked when
// the option is read, so a bad address is a bad command line (exit 2), not a failed run.
bool parse_serve_address(const std::string& spec, std::string* host, std::string* port,
                         std::string* error);

class LiveServer {
 public:
  // `spec`: "PORT" (loopback 127.0.0.1), "ADDR:PORT" or "[ADDR]:PORT" with a numeric IPv4 or IPv6
  // address; port 0 picks a free one. Null with `error` set when it cannot listen.
  static std::unique_ptr<LiveServer> start(const std::string& spec, const LiveServerLimits& limits,
                                           std::string* error);
  ~LiveServer();
  LiveServer(const LiveServer&) = delete;
  LiveServer& operator=(const LiveServer&) = delete;

  int port() const { return port_; }
  const std::string& url() const { return url_; }

  // Copies `snapshot` for the server unless it is reading the last one (then drops it and returns
  // false). Never blocks.
  bool publish(const LiveSnapshot& snapshot);

  // The mesh on demand: a GET /mesh.ply sets the request (answer 202, ask again); the loop sees
  // it after a frame, meshes the map (that frame takes longer, at the operator's request) and
  // hands over the PLY bytes, which the next GET /mesh.ply takes.
  bool mesh_requested() const { return mesh_requested_.load(); }
  void publish_mesh(std::string ply);

  int open_connections() const { return open_connections_.load(); }
  std::uint64_t responses() const { return responses_.load(); }
  std::uint64_t refused() const { return refused_.load(); }  // over the connection cap
  std::uint64_t timed_out() const { return timed_out_.load(); }

 private:
  struct Connection;
  LiveServer() = default;
  void serve();
  std::string respond(const std::string& request);
  std::string state_json();
  std::string render_bmp();
  std::string slice_bmp();
  void take_latest();

  int listen_fd_ = -1;
  int port_ = 0;
  std::string url_;
  LiveServerLimits limits_;
  std::thread thread_;
  std::atomic<bool> stop_{false};

  std::mutex mutex_;  // guards latest_ and latest_generation_
  LiveSnapshot latest_;
  std::uint64_t latest_generation_ = 0;
  LiveSnapshot serving_;  // the server thread's copy
  std::uint64_t serving_generation_ = 0;

  std::atomic<bool> mesh_requested_{false};
  std::string mesh_ply_;  // guarded by mutex_; empty: none ready

  std::atomic<int> open_connections_{0};
  std::atomic<std::uint64_t> responses_{0};
  std::atomic<std::uint64_t> refused_{0};
  std::atomic<std::uint64_t> timed_out_{0};
};

// A 24-bit BMP of `rgb` (rows top first); empty when the sizes do not match.
std::string bmp_bytes(int width, int height, const std::vector<std::uint8_t>& rgb);

// The page served at "/" (exposed for tests).
const char* live_page_html();

// A mesh as binary little-endian PLY (the layout of mesh.ply): vertex x, y, z (float) and scale
// (uchar), faces as uchar count + uint32 indices.
std::string mesh_ply_bytes(const float* xyz, const std::uint8_t* scale, std::size_t vertex_count,
                           const std::uint32_t* indices, std::size_t triangle_count);

}  // namespace octofuse::examples
