// The live view's HTTP server on loopback: the page and its data, garbage requests, clients that
// never read, a thousand connections; the mapping loop's publish() never waits on any of them.

#include "live_server.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <catch2/catch.hpp>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

using namespace octofuse::examples;

namespace {

// A connected socket; with `wait` false the connection may still be under way (EINPROGRESS), as
// a flood of clients would leave it when the server's accept queue is full.
int connect_to(int port, bool wait = true) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC | (wait ? 0 : SOCK_NONBLOCK), 0);
  REQUIRE(fd >= 0);
  sockaddr_in address;
  std::memset(&address, 0, sizeof(address));
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<std::uint16_t>(port));
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const int rc = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address));
  REQUIRE((rc == 0 || (!wait && errno == EINPROGRESS)));
  return fd;
}

// Sends `request` and reads until the server closes (at most 5 s); the whole answer.
std::string http_exchange(int port, const std::string& request) {
  const int fd = connect_to(port);
  if (!request.empty()) {
    REQUIRE(::send(fd, request.data(), request.size(), MSG_NOSIGNAL) ==
            static_cast<ssize_t>(request.size()));
  }
  std::string answer;
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(5);
  while (std::chrono::steady_clock::now() < give_up) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 100) <= 0) continue;
    char buffer[65536];
    const ssize_t got = ::recv(fd, buffer, sizeof(buffer), 0);
    if (got <= 0) break;
    answer.append(buffer, static_cast<std::size_t>(got));
  }
  ::close(fd);
  return answer;
}

// Whether `condition` holds within 10 s, asked every 10 ms: the server runs on its own thread.
template <typename Condition>
bool eventually(Condition condition) {
  const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!condition()) {
    if (std::chrono::steady_clock::now() >= give_up) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return true;
}

std::string body_of(const std::string& answer) {
  const std::size_t end = answer.find("\r\n\r\n");
  return end == std::string::npos ? std::string() : answer.substr(end + 4);
}

LiveSnapshot test_snapshot(long frame) {
  LiveSnapshot s;
  s.frame = frame;
  s.fps = 12.5;
  s.tracking = "tracked";
  s.map_bytes_used = 3u << 20;
  s.map_bytes_reserved = 64u << 20;
  s.blocks_used = 10;
  s.block_capacity = 1000;
  s.stage_ms = {1.0f, 2.0f, 3.0f, 4.5f};
  s.trajectory_p_W = {0.0f, 0.5f, 1.0f};
  s.width = 3;
  s.height = 2;
  // Row 0: red, green, blue; row 1: white, black, grey.
  s.rgb = {255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255, 0, 0, 0, 128, 128, 128};
  return s;
}

std::unique_ptr<LiveServer> start(LiveServerLimits limits = LiveServerLimits()) {
  std::string error;
  auto server = LiveServer::start("127.0.0.1:0", limits, &error);
  INFO(error);
  REQUIRE(server != nullptr);
  REQUIRE(server->port() > 0);
  return server;
}

}  // namespace

TEST_CASE("The live server serves the page, the state and the ray-cast", "[examples][live]") {
  auto server = start();
  CHECK(server->url() == "http://127.0.0.1:" + std::to_string(server->port()) + "/");

  const std::string page = http_exchange(server->port(), "GET / HTTP/1.1\r\nHost: x\r\n\r\n");
  CHECK(page.rfind("HTTP/1.0 200 OK\r\n", 0) == 0);
  CHECK(page.find("Content-Type: text/html") != std::string::npos);
  CHECK(body_of(page) == live_page_html());
  // Self-contained: nothing fetched from another host.
  CHECK(std::string(live_page_html()).find("http") == std::string::npos);
  CHECK(std::string(live_page_html()).find("//") == std::string(live_page_html()).find("// "));

  CHECK(body_of(http_exchange(server->port(), "GET /render.bmp HTTP/1.0\r\n\r\n")) ==
        "404 Not Found\n");  // nothing published yet
  REQUIRE(server->publish(test_snapshot(7)));
  const std::string state =
      body_of(http_exchange(server->port(), "GET /state.json HTTP/1.0\r\n\r\n"));
  CHECK(state ==
        "{\"frame\":7,\"fps\":12.5,\"tracking\":\"tracked\",\"map_bytes_used\":3145728,"
        "\"map_bytes_reserved\":67108864,\"blocks_used\":10,\"block_capacity\":1000,\"width\":3,"
        "\"height\":2,\"slice_width\":0,\"slice_z_m\":0,\"slice_max_m\":0,\"slice_version\":0,"
        "\"stage_ms\":[1,2,3,4.5],\"trajectory_p_W\":[0,0.5,1]}");

  const std::string bmp =
      body_of(http_exchange(server->port(), "GET /render.bmp?frame=7 HTTP/1.0\n\n"));
  // 54-byte header, then rows bottom first, BGR, padded to 12 bytes.
  REQUIRE(bmp.size() == 54u + 2u * 12u);
  CHECK(bmp.compare(0, 2, "BM") == 0);
  const std::string bottom_row("\xFF\xFF\xFF\x00\x00\x00\x80\x80\x80\x00\x00\x00", 12);
  const std::string top_row("\x00\x00\xFF\x00\xFF\x00\xFF\x00\x00\x00\x00\x00", 12);
  CHECK(bmp.substr(54, 12) == bottom_row);
  CHECK(bmp.substr(66, 12) == top_row);

  // The distance field's slice (--esdf): none in this snapshot, then one of 2 x 1 pixels.
  CHECK(body_of(http_exchange(server->port(), "GET /slice.bmp HTTP/1.0\r\n\r\n")) ==
        "404 Not Found\n");
  LiveSnapshot with_slice = test_snapshot(8);
  with_slice.slice_width = 2;
  with_slice.slice_height = 1;
  with_slice.slice_z_m = 1.25f;
  with_slice.slice_max_m = 1.0f;
  with_slice.slice_version = 5;
  with_slice.slice_rgb = {255, 0, 0, 128, 128, 128};
  REQUIRE(server->publish(with_slice));
  const std::string slice_state =
      body_of(http_exchange(server->port(), "GET /state.json HTTP/1.0\r\n\r\n"));
  CHECK(slice_state.find("\"slice_width\":2,\"slice_z_m\":1.25,\"slice_max_m\":1,"
                         "\"slice_version\":5") != std::string::npos);
  const std::string slice =
      body_of(http_exchange(server->port(), "GET /slice.bmp?v=5 HTTP/1.0\r\n\r\n"));
  REQUIRE(slice.size() == 54u + 8u);  // one row of 6 bytes padded to 8
  CHECK(slice.substr(54, 8) == std::string("\x00\x00\xFF\x80\x80\x80\x00\x00", 8));
}

TEST_CASE("The mesh on demand: asked for, made by the loop, taken once", "[examples][live]") {
  auto server = start();
  CHECK_FALSE(server->mesh_requested());
  CHECK(http_exchange(server->port(), "GET /mesh.ply HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 202", 0) ==
        0);
  CHECK(server->mesh_requested());
  // The loop's part: one triangle.
  const float xyz[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  const std::uint8_t scale[3] = {0, 1, 2};
  const std::uint32_t indices[3] = {0, 1, 2};
  const std::string ply = mesh_ply_bytes(xyz, scale, 3, indices, 1);
  const std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nproperty uchar scale\nelement face 1\n"
      "property list uchar uint vertex_indices\nend_header\n";
  REQUIRE(ply.size() == header.size() + 3 * 13 + 13);
  CHECK(ply.compare(0, header.size(), header) == 0);
  CHECK(ply[header.size() + 12] == 0);      // scale of vertex 0
  CHECK(ply[header.size() + 3 * 13] == 3);  // the face's vertex count
  server->publish_mesh(ply);
  CHECK_FALSE(server->mesh_requested());
  CHECK(body_of(http_exchange(server->port(), "GET /mesh.ply HTTP/1.0\r\n\r\n")) == ply);
  // Taken: the next request asks for a new one.
  CHECK(http_exchange(server->port(), "GET /mesh.ply HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 202", 0) ==
        0);
}

TEST_CASE("The live server answers garbage with an error and keeps serving", "[examples][live]") {
  auto server = start();
  const int port = server->port();
  CHECK(http_exchange(port, "POST / HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 405", 0) == 0);
  CHECK(http_exchange(port, "GET /etc/passwd HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 404", 0) == 0);
  CHECK(http_exchange(port, "GET /../../x HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 404", 0) == 0);
  CHECK(http_exchange(port, "hello\r\n\r\n").rfind("HTTP/1.0 400", 0) == 0);
  CHECK(
      http_exchange(port, std::string("GET /\x01\xff HTTP/1.0\r\n\r\n")).rfind("HTTP/1.0 400", 0) ==
      0);
  CHECK(http_exchange(port, std::string(9000, 'A')).rfind("HTTP/1.0 431", 0) == 0);
  CHECK(http_exchange(port, std::string("\0\0\0\n\n", 5)).rfind("HTTP/1.0 400", 0) == 0);
  // A client that connects and leaves, one that sends half a request and leaves.
  ::close(connect_to(port));
  const int half = connect_to(port);
  REQUIRE(::send(half, "GET / HT", 8, MSG_NOSIGNAL) == 8);
  ::close(half);
  CHECK(http_exchange(port, "GET / HTTP/1.0\r\n\r\n").rfind("HTTP/1.0 200", 0) == 0);
}

TEST_CASE("Silent, never-reading and a thousand clients cannot stall publish or the server",
          "[examples][live]") {
  LiveServerLimits limits;
  limits.max_connections = 16;
  limits.timeout_ms = 300;
  auto server = start(limits);
  const int port = server->port();
  LiveSnapshot big = test_snapshot(1);
  big.width = 640;
  big.height = 480;
  big.rgb.assign(640u * 480u * 3u, 77);  // a 900 KB answer, more than the socket buffers hold
  REQUIRE(server->publish(big));

  // Clients that ask for the big image and never read it, with a small receive buffer.
  std::vector<int> stuck;
  for (int i = 0; i < 4; ++i) {
    const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    const int small = 4096;
    ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &small, sizeof(small));
    sockaddr_in address;
    std::memset(&address, 0, sizeof(address));
    address.sin_family = AF_INET;
    address.sin_port = htons(static_cast<std::uint16_t>(port));
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    REQUIRE(::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof(address)) == 0);
    REQUIRE(::send(fd, "GET /render.bmp HTTP/1.0\r\n\r\n", 28, MSG_NOSIGNAL) == 28);
    stuck.push_back(fd);
  }
  // A thousand connections that say nothing (fewer if this process may not open that many files;
  // then the server runs out of descriptors too, which it must also survive).
  rlimit files;
  REQUIRE(::getrlimit(RLIMIT_NOFILE, &files) == 0);
  if (files.rlim_cur < 2200 && files.rlim_max > files.rlim_cur) {
    files.rlim_cur = std::min<rlim_t>(files.rlim_max, 2200);
    ::setrlimit(RLIMIT_NOFILE, &files);
    REQUIRE(::getrlimit(RLIMIT_NOFILE, &files) == 0);
  }
  const int flood = static_cast<int>(std::min<rlim_t>(1000, files.rlim_cur - 64));
  std::vector<int> silent;
  for (int i = 0; i < flood; ++i) silent.push_back(connect_to(port, false));

  // The mapping loop meanwhile: every publish returns, and each frame gets through within a few
  // tries (a server stalled while holding the snapshot would refuse them all). Tries rather than
  // a share of single tries: a loaded machine may run the server thread late mid-copy, which
  // says nothing of a stall.
  int frames_through = 0;
  for (int frame = 2; frame < 202; ++frame) {
    big.frame = frame;
    bool through = false;
    for (int attempt = 0; attempt < 200 && !through; ++attempt) {
      through = server->publish(big);
      std::this_thread::sleep_for(std::chrono::milliseconds(through ? 2 : 1));
    }
    if (through) ++frames_through;
  }
  CHECK(frames_through == 200);
  CHECK(server->open_connections() <= limits.max_connections);
  CHECK(server->refused() > 0);

  // Once the flood stops and the deadlines pass, a well-behaved client is served again.
  for (const int fd : silent) ::close(fd);
  std::this_thread::sleep_for(std::chrono::milliseconds(2 * limits.timeout_ms));
  // The never-reading ones, at least (polled: a loaded machine may run the server late).
  CHECK(eventually([&] { return server->timed_out() >= 4; }));
  big.frame = 999;
  bool last_published = false;
  for (int attempt = 0; attempt < 100 && !last_published; ++attempt) {
    last_published = server->publish(big);
  }
  REQUIRE(last_published);
  const std::string state = body_of(http_exchange(port, "GET /state.json HTTP/1.0\r\n\r\n"));
  CHECK(state.find("\"frame\":999,") != std::string::npos);
  for (const int fd : stuck) ::close(fd);
  CHECK(eventually([&] { return server->open_connections() == 0; }));
}

TEST_CASE("--serve addresses: loopback by default, numeric only, bad specs refused",
          "[examples][live]") {
  std::string error;
  auto port_only = LiveServer::start("0", LiveServerLimits(), &error);
  REQUIRE(port_only != nullptr);
  CHECK(port_only->url().rfind("http://127.0.0.1:", 0) == 0);
  auto v6 = LiveServer::start("[::1]:0", LiveServerLimits(), &error);
  if (v6 != nullptr) CHECK(v6->url().rfind("http://[::1]:", 0) == 0);  // hosts without IPv6
  for (const char* bad : {"", "abc", "127.0.0.1:", "127.0.0.1:99999", "example.com:80", "[::1]80",
                          "1.2.3.4.5:80", "127.0.0.1:-1"}) {
    INFO(bad);
    CHECK(LiveServer::start(bad, LiveServerLimits(), &error) == nullptr);
    CHECK(error.rfind("--serve", 0) == 0);
  }
}
