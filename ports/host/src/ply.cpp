#include "octofuse/ports/host/ply.hpp"
#include "octofuse/ports/host/read_file.hpp"

#include "octofuse/ports/host/atomic_file.hpp"
#include "octofuse/ports/host/host_buffer.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>

namespace octofuse::host {
namespace {

// PLY binary_little_endian: values are stored in host order on little-endian machines, and
// converted byte by byte otherwise.
void put_u32(std::uint8_t* out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out[i] = static_cast<std::uint8_t>(v >> (8 * i));
}
std::uint32_t get_u32(const std::uint8_t* in) {
  return static_cast<std::uint32_t>(in[0]) | (static_cast<std::uint32_t>(in[1]) << 8) |
         (static_cast<std::uint32_t>(in[2]) << 16) | (static_cast<std::uint32_t>(in[3]) << 24);
}
void put_f32(std::uint8_t* out, float f) {
  std::uint32_t bits;
  std::memcpy(&bits, &f, 4);
  put_u32(out, bits);
}
float get_f32(const std::uint8_t* in) {
  const std::uint32_t bits = get_u32(in);
  float f;
  std::memcpy(&f, &bits, 4);
  return f;
}

struct FileCloser {
  std::FILE* file;
  ~FileCloser() {
    if (file != nullptr) std::fclose(file);
  }
};

}  // namespace

Status write_ply(const char* path, const MeshView& mesh, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  for (std::size_t i = 0; i < mesh.triangle_count * 3; ++i) {
    if (mesh.indices[i] >= mesh.vertex_count) {
      err.set("%s: triangle %zu refers to vertex %u of %zu", path, i / 3, mesh.indices[i],
              mesh.vertex_count);
      return StatusCode::invalid_argument;
    }
  }
  // Through a temporary renamed into place: a crash leaves the previous mesh or this one, whole.
  AtomicFile atomic;
  const Status opened = atomic.open(path);
  if (!opened.ok()) {
    err.set("%s", atomic.last_error());
    return opened;
  }
  std::FILE* file = atomic.file();
  const bool with_scale = mesh.vertex_scale != nullptr;
  std::fprintf(file,
               "ply\nformat binary_little_endian 1.0\ncomment octofuse mesh, metres\n"
               "element vertex %zu\nproperty float x\nproperty float y\nproperty float z\n%s"
               "element face %zu\nproperty list uchar uint vertex_indices\nend_header\n",
               mesh.vertex_count, with_scale ? "property uchar scale\n" : "", mesh.triangle_count);
  HostBuffer<std::uint8_t> buffer;
  const std::size_t vertex_bytes = with_scale ? 13 : 12;
  buffer.resize(mesh.vertex_count * vertex_bytes);
  for (std::size_t i = 0; i < mesh.vertex_count; ++i) {
    std::uint8_t* out = buffer.data() + i * vertex_bytes;
    for (int k = 0; k < 3; ++k) put_f32(out + 4 * k, mesh.vertices[i][k]);
    if (with_scale) out[12] = mesh.vertex_scale[i];
  }
  bool ok = std::fwrite(buffer.data(), 1, buffer.size(), file) == buffer.size();
  buffer.resize(mesh.triangle_count * 13);
  for (std::size_t t = 0; t < mesh.triangle_count; ++t) {
    std::uint8_t* out = buffer.data() + t * 13;
    out[0] = 3;
    for (int k = 0; k < 3; ++k) put_u32(out + 1 + 4 * k, mesh.indices[3 * t + k]);
  }
  ok = ok && std::fwrite(buffer.data(), 1, buffer.size(), file) == buffer.size();
  if (!ok) {
    err.set("%s: write failed", path);
    return StatusCode::data_loss;  // `atomic` removes the temporary
  }
  const Status committed = atomic.commit();
  if (!committed.ok()) err.set("%s", atomic.last_error());
  return committed;
}

Status read_ply_into(const char* path, const PlyMeshTarget& target, ErrorText* error) {
  ErrorText scratch;
  ErrorText& err = error != nullptr ? *error : scratch;
  std::FILE* file = open_regular_for_reading(path);
  if (file == nullptr) {
    err.set("%s: cannot open (%s)", path, open_failure_text(errno));
    return StatusCode::unavailable;
  }
  FileCloser closer{file};

  // Header: the vertex element is x, y, z floats plus an optional uchar scale (before or after
  // the coordinates); the face element is one list of uchar count + uint/int indices.
  char line[256];
  int line_number = 0;
  bool binary_le = false;
  bool saw_end = false;
  enum class Element { none, vertex, face, other } element = Element::none;
  unsigned long long vertex_count = 0, face_count = 0;
  int vertex_props = 0;
  int scale_position = -1;  // property index of "scale" within a vertex
  int xyz_seen = 0;
  bool face_list_ok = false;
  while (std::fgets(line, sizeof(line), file) != nullptr) {
    ++line_number;
    line[std::strcspn(line, "\r\n")] = '\0';
    if (line_number == 1) {
      if (std::strcmp(line, "ply") != 0) {
        err.set("%s: not a PLY file (first line is not \"ply\")", path);
        return StatusCode::data_loss;
      }
      continue;
    }
    char a[64] = {}, b[64] = {}, c[64] = {}, d[64] = {}, e[64] = {};
    const int n = std::sscanf(line, "%63s %63s %63s %63s %63s", a, b, c, d, e);
    if (n <= 0) continue;
    if (std::strcmp(a, "format") == 0) {
      binary_le = n >= 2 && std::strcmp(b, "binary_little_endian") == 0;
    } else if (std::strcmp(a, "comment") == 0 || std::strcmp(a, "obj_info") == 0) {
    } else if (std::strcmp(a, "element") == 0 && n == 3) {
      const unsigned long long count = std::strtoull(c, nullptr, 10);
      if (std::strcmp(b, "vertex") == 0) {
        element = Element::vertex;
        vertex_count = count;
      } else if (std::strcmp(b, "face") == 0) {
        element = Element::face;
        face_count = count;
      } else {
        element = Element::other;
      }
    } else if (std::strcmp(a, "property") == 0) {
      if (element == Element::vertex) {
        if (n == 3 && std::strcmp(b, "float") == 0 &&
            (std::strcmp(c, "x") == 0 || std::strcmp(c, "y") == 0 || std::strcmp(c, "z") == 0) &&
            c[0] - 'x' == xyz_seen) {
          ++xyz_seen;
        } else if (n == 3 && std::strcmp(b, "uchar") == 0 && std::strcmp(c, "scale") == 0 &&
                   scale_position < 0) {
          scale_position = vertex_props;
        } else {
          err.set("%s:%d: unsupported vertex property \"%s\"", path, line_number, line);
          return StatusCode::data_loss;
        }
        ++vertex_props;
      } else if (element == Element::face) {
        face_list_ok = n == 5 && std::strcmp(b, "list") == 0 && std::strcmp(c, "uchar") == 0 &&
                       (std::strcmp(d, "uint") == 0 || std::strcmp(d, "int") == 0) &&
                       std::strcmp(e, "vertex_indices") == 0;
        if (!face_list_ok) {
          err.set("%s:%d: unsupported face property \"%s\"", path, line_number, line);
          return StatusCode::data_loss;
        }
      } else {
        err.set("%s:%d: property outside the vertex/face elements", path, line_number);
        return StatusCode::data_loss;
      }
    } else if (std::strcmp(a, "end_header") == 0) {
      saw_end = true;
      break;
    } else {
      err.set("%s:%d: unexpected header line \"%s\"", path, line_number, line);
      return StatusCode::data_loss;
    }
  }
  if (!saw_end || !binary_le || xyz_seen != 3 || (face_count > 0 && !face_list_ok)) {
    err.set("%s: header is not binary_little_endian with float x y z vertices and a face list",
            path);
    return StatusCode::data_loss;
  }
  // Guard against absurd counts before reserving memory for them.
  constexpr unsigned long long kMaxElements = 1ull << 31;
  if (vertex_count > kMaxElements || face_count > kMaxElements) {
    err.set("%s: element counts too large (%llu vertices, %llu faces)", path, vertex_count,
            face_count);
    return StatusCode::data_loss;
  }

  const std::size_t vertex_bytes = scale_position >= 0 ? 13 : 12;
  // The body must be exactly what the header promises (13 bytes per triangle): checked before
  // anything is reserved, so a header claiming billions of elements costs nothing, and a file
  // with bytes after its last face is refused as not ours.
  const long body_start = std::ftell(file);
  if (body_start < 0 || std::fseek(file, 0, SEEK_END) != 0) {
    err.set("%s: cannot seek", path);
    return StatusCode::data_loss;
  }
  const long file_end = std::ftell(file);
  if (file_end < body_start || std::fseek(file, body_start, SEEK_SET) != 0) {
    err.set("%s: cannot seek", path);
    return StatusCode::data_loss;
  }
  const unsigned long long body_bytes = static_cast<unsigned long long>(file_end - body_start);
  const unsigned long long expected_bytes = vertex_count * vertex_bytes + face_count * 13ull;
  if (body_bytes < expected_bytes) {
    err.set(
        "%s: truncated: the header promises %llu vertices and %llu faces (%llu bytes), the "
        "body holds %llu bytes",
        path, vertex_count, face_count, expected_bytes, body_bytes);
    return StatusCode::data_loss;
  }
  if (body_bytes > expected_bytes) {
    err.set("%s: %llu bytes after the last face", path, body_bytes - expected_bytes);
    return StatusCode::data_loss;
  }
  HostBuffer<std::uint8_t> buffer;
  buffer.resize(static_cast<std::size_t>(vertex_count) * vertex_bytes);
  if (std::fread(buffer.data(), 1, buffer.size(), file) != buffer.size()) {
    err.set("%s: truncated in the vertex data (%llu vertices expected)", path, vertex_count);
    return StatusCode::data_loss;
  }
  Eigen::Vector3f* vertices = nullptr;
  std::uint32_t* indices = nullptr;
  std::uint8_t* scale = nullptr;
  if (!target.allocate(target.context, static_cast<std::size_t>(vertex_count),
                       static_cast<std::size_t>(face_count), scale_position >= 0, &vertices,
                       &indices, &scale)) {
    err.set("%s: no storage for %llu vertices and %llu faces", path, vertex_count, face_count);
    return StatusCode::resource_exhausted;
  }
  for (std::size_t i = 0; i < vertex_count; ++i) {
    const std::uint8_t* in = buffer.data() + i * vertex_bytes;
    int offset = 0;
    int coordinate = 0;
    for (int prop = 0; prop < vertex_props; ++prop) {
      if (prop == scale_position) {
        scale[i] = in[offset];
        offset += 1;
      } else {
        vertices[i][coordinate++] = get_f32(in + offset);
        offset += 4;
      }
    }
  }
  std::uint8_t face[13];
  for (std::size_t t = 0; t < face_count; ++t) {
    if (std::fread(face, 1, 13, file) != 13) {
      err.set("%s: truncated in face %zu of %llu", path, t, face_count);
      return StatusCode::data_loss;
    }
    if (face[0] != 3) {
      err.set("%s: face %zu has %u vertices, only triangles are supported", path, t, face[0]);
      return StatusCode::data_loss;
    }
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t index = get_u32(face + 1 + 4 * k);
      if (index >= vertex_count) {
        err.set("%s: face %zu refers to vertex %u of %llu", path, t, index, vertex_count);
        return StatusCode::data_loss;
      }
      indices[3 * t + k] = index;
    }
  }
  return ok_status();
}

}  // namespace octofuse::host
