#include "live_server.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "octofuse/ports/host/json_writer.hpp"

namespace octofuse::examples {

namespace {

using SteadyClock = std::chrono::steady_clock;

constexpr int kPollIntervalMs = 50;  // how soon stop() is seen
constexpr int kAcceptsPerPoll = 64;

bool parse_port(const std::string& text, int* port) {
  if (text.empty() || text.size() > 5) return false;
  int value = 0;
  for (const char c : text) {
    if (c < '0' || c > '9') return false;
    value = value * 10 + (c - '0');
  }
  if (value > 65535) return false;
  *port = value;
  return true;
}

std::string http_response(const char* status, const char* content_type, const std::string& body) {
  std::string out = std::string("HTTP/1.0 ") + status + "\r\nContent-Type: " + content_type +
                    "\r\nContent-Length: " + std::to_string(body.size()) +
                    "\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n";
  out += body;
  return out;
}

std::string error_response(const char* status) {
  return http_response(status, "text/plain; charset=utf-8", std::string(status) + "\n");
}

void put_u32(std::string& out, std::size_t at, std::uint32_t value) {
  for (int i = 0; i < 4; ++i) out[at + i] = static_cast<char>((value >> (8 * i)) & 0xFF);
}

}  // namespace

struct LiveServer::Connection {
  int fd = -1;
  std::string in;
  std::string out;
  std::size_t sent = 0;
  bool responding = false;
  SteadyClock::time_point deadline;
};

namespace {
// The passive TCP address of a numeric host and port (no name lookup); null when either is not
// numeric. The caller frees it with freeaddrinfo().
addrinfo* resolve_numeric(const std::string& host, const std::string& port) {
  addrinfo hints;
  std::memset(&hints, 0, sizeof(hints));
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_NUMERICHOST | AI_NUMERICSERV | AI_PASSIVE;
  addrinfo* found = nullptr;
  if (::getaddrinfo(host.c_str(), port.c_str(), &hints, &found) != 0) return nullptr;
  return found;
}
}  // namespace

bool parse_serve_address(const std::string& spec, std::string* host_out, std::string* port_out,
                         std::string* error) {
  std::string host = "127.0.0.1";
  std::string port_text = spec;
  if (!spec.empty() && spec[0] == '[') {
    const std::size_t close = spec.find("]:");
    if (close == std::string::npos) {
      *error = "needs [ADDR]:PORT, not '" + spec + "'";
      return false;
    }
    host = spec.substr(1, close - 1);
    port_text = spec.substr(close + 2);
  } else if (spec.find(':') != std::string::npos) {
    const std::size_t colon = spec.rfind(':');
    host = spec.substr(0, colon);
    port_text = spec.substr(colon + 1);
    if (host == "localhost") host = "127.0.0.1";
  }
  int port = 0;
  if (!parse_port(port_text, &port) || host.empty()) {
    *error = "needs PORT, ADDR:PORT or [ADDR]:PORT with a numeric address, not '" + spec + "'";
    return false;
  }
  addrinfo* found = resolve_numeric(host, port_text);
  if (found == nullptr) {
    *error = "needs a numeric IPv4 or IPv6 address, not '" + host + "'";
    return false;
  }
  ::freeaddrinfo(found);
  *host_out = host;
  *port_out = port_text;
  return true;
}

std::unique_ptr<LiveServer> LiveServer::start(const std::string& spec,
                                              const LiveServerLimits& limits, std::string* error) {
  std::string host;
  std::string port_text;
  std::string why;
  if (!parse_serve_address(spec, &host, &port_text, &why)) {
    *error = "--serve " + why;
    return nullptr;
  }
  int port = 0;
  addrinfo* found = resolve_numeric(host, port_text);
  if (found == nullptr) {
    *error = "--serve: '" + host + "' is not a numeric IPv4 or IPv6 address";
    return nullptr;
  }
  const int family = found->ai_family;
  const int fd = ::socket(family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    ::freeaddrinfo(found);
    *error = std::string("--serve: socket: ") + std::strerror(errno);
    return nullptr;
  }
  const int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  if (family == AF_INET6) ::setsockopt(fd, IPPROTO_IPV6, IPV6_V6ONLY, &one, sizeof(one));
  const bool bound = ::bind(fd, found->ai_addr, found->ai_addrlen) == 0;
  ::freeaddrinfo(found);
  if (!bound || ::listen(fd, 64) != 0) {
    *error = "--serve: cannot listen on " + spec + ": " + std::strerror(errno);
    ::close(fd);
    return nullptr;
  }
  sockaddr_storage address;
  socklen_t length = sizeof(address);
  if (::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) != 0) {
    *error = std::string("--serve: getsockname: ") + std::strerror(errno);
    ::close(fd);
    return nullptr;
  }
  port = ntohs(family == AF_INET6 ? reinterpret_cast<sockaddr_in6*>(&address)->sin6_port
                                  : reinterpret_cast<sockaddr_in*>(&address)->sin_port);

  std::unique_ptr<LiveServer> server(new LiveServer());
  server->listen_fd_ = fd;
  server->port_ = port;
  server->limits_ = limits;
  if (server->limits_.max_connections < 1) server->limits_.max_connections = 1;
  server->url_ =
      "http://" + (family == AF_INET6 ? "[" + host + "]" : host) + ":" + std::to_string(port) + "/";
  server->thread_ = std::thread([s = server.get()] { s->serve(); });
  return server;
}

LiveServer::~LiveServer() {
  stop_.store(true);
  if (thread_.joinable()) thread_.join();
  if (listen_fd_ >= 0) ::close(listen_fd_);
}

bool LiveServer::publish(const LiveSnapshot& snapshot) {
  std::unique_lock<std::mutex> lock(mutex_, std::try_to_lock);
  if (!lock.owns_lock()) return false;
  latest_ = snapshot;  // vectors keep their capacity: no allocation once sizes settle
  ++latest_generation_;
  return true;
}

void LiveServer::publish_mesh(std::string ply) {
  std::lock_guard<std::mutex> lock(mutex_);
  mesh_ply_ = std::move(ply);
  mesh_requested_.store(false);
}

std::string mesh_ply_bytes(const float* xyz, const std::uint8_t* scale, std::size_t vertex_count,
                           const std::uint32_t* indices, std::size_t triangle_count) {
  std::string out =
      "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(vertex_count) +
      "\nproperty float x\nproperty float y\nproperty float z\n"
      "property uchar scale\nelement face " +
      std::to_string(triangle_count) + "\nproperty list uchar uint vertex_indices\nend_header\n";
  out.reserve(out.size() + vertex_count * 13 + triangle_count * 13);
  auto put = [&out](const void* data, std::size_t bytes) {
    out.append(static_cast<const char*>(data), bytes);  // hosts are little-endian (x86, ARM)
  };
  for (std::size_t v = 0; v < vertex_count; ++v) {
    put(xyz + 3 * v, 3 * sizeof(float));
    put(scale + v, 1);
  }
  const std::uint8_t three = 3;
  for (std::size_t t = 0; t < triangle_count; ++t) {
    put(&three, 1);
    put(indices + 3 * t, 3 * sizeof(std::uint32_t));
  }
  return out;
}

void LiveServer::serve() {
  std::vector<Connection> connections;
  connections.reserve(static_cast<std::size_t>(limits_.max_connections));
  std::vector<pollfd> fds;
  fds.reserve(connections.capacity() + 1);
  // Out of file descriptors, a pending connection keeps the listening socket readable: stop
  // listening for a moment instead of spinning on it.
  SteadyClock::time_point accept_paused_until;
  auto close_connection = [&](std::size_t i) {
    ::close(connections[i].fd);
    connections[i] = std::move(connections.back());
    connections.pop_back();
  };
  while (!stop_.load()) {
    fds.clear();
    const bool listening = SteadyClock::now() >= accept_paused_until;
    fds.push_back(pollfd{listening ? listen_fd_ : -1, POLLIN, 0});
    for (const Connection& c : connections) {
      fds.push_back(pollfd{c.fd, static_cast<short>(c.responding ? POLLOUT : POLLIN), 0});
    }
    const int ready = ::poll(fds.data(), fds.size(), kPollIntervalMs);
    if (ready < 0 && errno != EINTR) break;
    const auto now = SteadyClock::now();

    // Walk the connections polled this round backwards, so closing one (swap with the last)
    // never skips another.
    for (std::size_t i = fds.size() - 1; i >= 1; --i) {
      Connection& c = connections[i - 1];
      const short events = fds[i].revents;
      bool close_it = false;
      if ((events & (POLLERR | POLLNVAL)) != 0) close_it = true;
      if (!close_it && !c.responding && (events & (POLLIN | POLLHUP)) != 0) {
        char buffer[4096];
        for (;;) {
          const ssize_t got = ::recv(c.fd, buffer, sizeof(buffer), 0);
          if (got > 0) {
            c.in.append(buffer, static_cast<std::size_t>(got));
            if (c.in.size() > limits_.max_request_bytes) break;
            continue;
          }
          if (got == 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR)) {
            close_it = true;  // the client left before asking
          }
          if (got < 0 && errno == EINTR) continue;
          break;
        }
        if (c.in.size() > limits_.max_request_bytes) {
          c.out = error_response("431 Request Header Fields Too Large");
          c.responding = true;
          close_it = false;
        } else if (c.in.find("\r\n\r\n") != std::string::npos ||
                   c.in.find("\n\n") != std::string::npos) {
          c.out = respond(c.in);
          c.responding = true;
          close_it = false;
        }
      }
      if (!close_it && c.responding && (c.sent < c.out.size())) {
        const ssize_t put =
            ::send(c.fd, c.out.data() + c.sent, c.out.size() - c.sent, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (put > 0) {
          c.sent += static_cast<std::size_t>(put);
        } else if (put < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
          close_it = true;
        }
        if (c.sent == c.out.size()) {
          responses_.fetch_add(1);
          ::shutdown(c.fd, SHUT_WR);
          close_it = true;
        }
      }
      if (!close_it && now >= c.deadline) {
        timed_out_.fetch_add(1);
        close_it = true;
      }
      if (close_it) close_connection(i - 1);
    }

    if ((fds[0].revents & POLLIN) != 0) {
      for (int n = 0; n < kAcceptsPerPoll; ++n) {
        const int fd = ::accept4(listen_fd_, nullptr, nullptr, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (fd < 0) {
          if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM) {
            accept_paused_until = now + std::chrono::milliseconds(kPollIntervalMs);
          }
          break;
        }
        if (connections.size() >= static_cast<std::size_t>(limits_.max_connections)) {
          ::close(fd);
          refused_.fetch_add(1);
          continue;
        }
        Connection c;
        c.fd = fd;
        c.deadline = now + std::chrono::milliseconds(limits_.timeout_ms);
        connections.push_back(std::move(c));
      }
    }
    open_connections_.store(static_cast<int>(connections.size()));
  }
  for (const Connection& c : connections) ::close(c.fd);
  open_connections_.store(0);
}

std::string LiveServer::respond(const std::string& request) {
  const std::size_t line_end = request.find('\n');
  std::string line = request.substr(0, line_end);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  for (const char c : line) {
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) > 0x7E) {
      return error_response("400 Bad Request");
    }
  }
  const std::size_t first_space = line.find(' ');
  const std::size_t second_space =
      first_space == std::string::npos ? std::string::npos : line.find(' ', first_space + 1);
  if (second_space == std::string::npos || line.compare(second_space + 1, 7, "HTTP/1.") != 0) {
    return error_response("400 Bad Request");
  }
  const std::string method = line.substr(0, first_space);
  std::string path = line.substr(first_space + 1, second_space - first_space - 1);
  path = path.substr(0, path.find('?'));
  if (method != "GET") return error_response("405 Method Not Allowed");
  if (path == "/") return http_response("200 OK", "text/html; charset=utf-8", live_page_html());
  if (path == "/state.json") return http_response("200 OK", "application/json", state_json());
  if (path == "/mesh.ply") {
    std::string ply;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ply.swap(mesh_ply_);
    }
    if (ply.empty()) {
      mesh_requested_.store(true);
      return http_response("202 Accepted", "text/plain; charset=utf-8",
                           "meshing the map: ask again\n");
    }
    return http_response("200 OK", "application/octet-stream", ply);
  }
  if (path == "/render.bmp") {
    const std::string bmp = render_bmp();
    if (bmp.empty()) return error_response("404 Not Found");
    return http_response("200 OK", "image/bmp", bmp);
  }
  if (path == "/slice.bmp") {
    const std::string bmp = slice_bmp();
    if (bmp.empty()) return error_response("404 Not Found");
    return http_response("200 OK", "image/bmp", bmp);
  }
  return error_response("404 Not Found");
}

std::string LiveServer::state_json() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (serving_generation_ != latest_generation_) {
      serving_ = latest_;
      serving_generation_ = latest_generation_;
    }
  }
  const LiveSnapshot& s = serving_;
  host::JsonWriter json;
  json.begin_object();
  json.key("frame").value(static_cast<std::int64_t>(s.frame));
  json.key("fps").value(s.fps);
  json.key("tracking").value(s.tracking.c_str());
  json.key("map_bytes_used").value(s.map_bytes_used);
  json.key("map_bytes_reserved").value(s.map_bytes_reserved);
  json.key("blocks_used").value(static_cast<std::uint64_t>(s.blocks_used));
  json.key("block_capacity").value(static_cast<std::uint64_t>(s.block_capacity));
  json.key("width").value(s.width);
  json.key("height").value(s.height);
  json.key("slice_width").value(s.slice_width);
  json.key("slice_z_m").value(std::round(static_cast<double>(s.slice_z_m) * 1e3) / 1e3);
  json.key("slice_max_m").value(static_cast<double>(s.slice_max_m));
  json.key("slice_version").value(s.slice_version);
  json.key("stage_ms").begin_array();
  // Microseconds and tenths of a millimetre are plenty for a plot, and keep the text short.
  for (const float ms : s.stage_ms) json.value(std::round(static_cast<double>(ms) * 1e3) / 1e3);
  json.end_array();
  json.key("trajectory_p_W").begin_array();
  for (const float p : s.trajectory_p_W) json.value(std::round(static_cast<double>(p) * 1e4) / 1e4);
  json.end_array();
  json.end_object();
  return std::string(json.c_str(), json.size());
}

void LiveServer::take_latest() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (serving_generation_ != latest_generation_) {
    serving_ = latest_;
    serving_generation_ = latest_generation_;
  }
}

std::string LiveServer::render_bmp() {
  take_latest();
  return bmp_bytes(serving_.width, serving_.height, serving_.rgb);
}

std::string LiveServer::slice_bmp() {
  take_latest();
  return bmp_bytes(serving_.slice_width, serving_.slice_height, serving_.slice_rgb);
}

std::string bmp_bytes(int width, int height, const std::vector<std::uint8_t>& rgb) {
  if (width <= 0 || height <= 0 ||
      rgb.size() != static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * 3) {
    return std::string();
  }
  // 24-bit BMP: BGR, rows bottom first, each padded to 4 bytes.
  const std::size_t row_bytes = (static_cast<std::size_t>(width) * 3 + 3) / 4 * 4;
  const std::size_t pixel_bytes = row_bytes * static_cast<std::size_t>(height);
  std::string out(54 + pixel_bytes, '\0');
  out[0] = 'B';
  out[1] = 'M';
  put_u32(out, 2, static_cast<std::uint32_t>(out.size()));
  put_u32(out, 10, 54);
  put_u32(out, 14, 40);
  put_u32(out, 18, static_cast<std::uint32_t>(width));
  put_u32(out, 22, static_cast<std::uint32_t>(height));
  out[26] = 1;   // planes
  out[28] = 24;  // bits per pixel
  put_u32(out, 34, static_cast<std::uint32_t>(pixel_bytes));
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* src = rgb.data() + static_cast<std::size_t>(y) * width * 3;
    char* dst = &out[54 + static_cast<std::size_t>(height - 1 - y) * row_bytes];
    for (int x = 0; x < width; ++x) {
      dst[3 * x + 0] = static_cast<char>(src[3 * x + 2]);
      dst[3 * x + 1] = static_cast<char>(src[3 * x + 1]);
      dst[3 * x + 2] = static_cast<char>(src[3 * x + 0]);
    }
  }
  return out;
}

}  // namespace octofuse::examples
