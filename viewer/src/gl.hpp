#pragma once
/// @file gl.hpp (private to hc::viewer)
/// OpenGL 3.3 core entry points and small helpers: shader programs, meshes (VAO + VBO + EBO),
/// an off-screen framebuffer. The core functions are linked directly from libGL (GLVND
/// exports every core entry point on Linux), so no loader is needed.

#define GL_GLEXT_PROTOTYPES 1
#include <GL/glcorearb.h>

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace hc::viewer::gl {

/// A linked vertex + fragment program. @throws hc::ResourceError with the compiler's log.
class Program {
 public:
  Program() = default;
  Program(const char* vertex_source, const char* fragment_source);
  ~Program();
  Program(const Program&) = delete;
  Program& operator=(const Program&) = delete;
  Program(Program&& other) noexcept : id_(other.id_) { other.id_ = 0; }
  Program& operator=(Program&& other) noexcept;

  void use() const { glUseProgram(id_); }
  GLint uniform(const char* name) const { return glGetUniformLocation(id_, name); }
  void set(const char* name, const Eigen::Matrix4f& m) const;
  void set(const char* name, const Eigen::Matrix3f& m) const;
  void set(const char* name, const Eigen::Vector3f& v) const;
  void set(const char* name, const Eigen::Vector2f& v) const;
  void set(const char* name, float v) const;
  void set(const char* name, int v) const;

 private:
  GLuint id_ = 0;
};

/// Interleaved position (3 floats) + normal (3 floats) vertices (attributes 0 and 1) with
/// 32-bit indices, and optionally a per-vertex colour (3 floats, attribute 2, own buffer).
class Mesh {
 public:
  Mesh() = default;
  ~Mesh();
  Mesh(const Mesh&) = delete;
  Mesh& operator=(const Mesh&) = delete;

  /// Uploads (replacing any earlier data). `primitive` is GL_TRIANGLES, GL_LINES, GL_POINTS ...
  /// `colours`: empty (attribute 2 off: shaders use a uniform colour) or 3 floats per vertex.
  void upload(const std::vector<float>& vertices, const std::vector<std::uint32_t>& indices, GLenum primitive,
              bool dynamic = false, const std::vector<float>& colours = {});
  bool has_colours() const { return has_colours_; }
  void draw() const;
  std::size_t index_count() const { return count_; }
  bool empty() const { return count_ == 0; }

 private:
  void release();
  GLuint vao_ = 0, vbo_ = 0, ebo_ = 0, cbo_ = 0;
  std::size_t count_ = 0;
  bool has_colours_ = false;
  GLenum primitive_ = GL_TRIANGLES;
};

/// Colour (RGBA8) + depth (24 bit) render target.
class Framebuffer {
 public:
  Framebuffer() = default;
  ~Framebuffer();
  Framebuffer(const Framebuffer&) = delete;
  Framebuffer& operator=(const Framebuffer&) = delete;
  /// (Re)allocates when the size changed. @throws hc::ResourceError if incomplete.
  void ensure(int width, int height);
  GLuint id() const { return fbo_; }
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  void release();
  GLuint fbo_ = 0, colour_ = 0, depth_ = 0;
  int width_ = 0, height_ = 0;
};

}  // namespace hc::viewer::gl
