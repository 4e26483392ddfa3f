/// OpenGL helpers (gl.hpp).

#include "gl.hpp"

#include "hc/common/error.hpp"

#include <cstdint>
#include <string>

namespace hc::viewer::gl {

namespace {

GLuint compile(GLenum type, const char* source) {
  const GLuint shader = glCreateShader(type);
  glShaderSource(shader, 1, &source, nullptr);
  glCompileShader(shader);
  GLint ok = 0;
  glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
  if (ok == 0) {
    char log[2048] = {};
    glGetShaderInfoLog(shader, sizeof log, nullptr, log);
    glDeleteShader(shader);
    throw ResourceError(std::string("viewer: the OpenGL driver rejected a ") +
                        (type == GL_VERTEX_SHADER ? "vertex" : "fragment") + " shader: " + log);
  }
  return shader;
}

}  // namespace

Program::Program(const char* vertex_source, const char* fragment_source) {
  const GLuint vs = compile(GL_VERTEX_SHADER, vertex_source);
  const GLuint fs = compile(GL_FRAGMENT_SHADER, fragment_source);
  id_ = glCreateProgram();
  glAttachShader(id_, vs);
  glAttachShader(id_, fs);
  glLinkProgram(id_);
  glDeleteShader(vs);
  glDeleteShader(fs);
  GLint ok = 0;
  glGetProgramiv(id_, GL_LINK_STATUS, &ok);
  if (ok == 0) {
    char log[2048] = {};
    glGetProgramInfoLog(id_, sizeof log, nullptr, log);
    glDeleteProgram(id_);
    id_ = 0;
    throw ResourceError(std::string("viewer: the OpenGL driver could not link a shader program: ") + log);
  }
}

Program::~Program() {
  if (id_ != 0) glDeleteProgram(id_);
}

Program& Program::operator=(Program&& other) noexcept {
  if (this != &other) {
    if (id_ != 0) glDeleteProgram(id_);
    id_ = other.id_;
    other.id_ = 0;
  }
  return *this;
}

void Program::set(const char* name, const Eigen::Matrix4f& m) const { glUniformMatrix4fv(uniform(name), 1, GL_FALSE, m.data()); }
void Program::set(const char* name, const Eigen::Matrix3f& m) const { glUniformMatrix3fv(uniform(name), 1, GL_FALSE, m.data()); }
void Program::set(const char* name, const Eigen::Vector3f& v) const { glUniform3f(uniform(name), v.x(), v.y(), v.z()); }
void Program::set(const char* name, const Eigen::Vector2f& v) const { glUniform2f(uniform(name), v.x(), v.y()); }
void Program::set(const char* name, float v) const { glUniform1f(uniform(name), v); }
void Program::set(const char* name, int v) const { glUniform1i(uniform(name), v); }

Mesh::~Mesh() { release(); }

void Mesh::release() {
  if (ebo_ != 0) glDeleteBuffers(1, &ebo_);
  if (vbo_ != 0) glDeleteBuffers(1, &vbo_);
  if (cbo_ != 0) glDeleteBuffers(1, &cbo_);
  if (vao_ != 0) glDeleteVertexArrays(1, &vao_);
  vao_ = vbo_ = ebo_ = cbo_ = 0;
  count_ = 0;
  has_colours_ = false;
}

void Mesh::upload(const std::vector<float>& vertices, const std::vector<std::uint32_t>& indices, GLenum primitive,
                  bool dynamic, const std::vector<float>& colours) {
  if (vao_ == 0) {
    glGenVertexArrays(1, &vao_);
    glGenBuffers(1, &vbo_);
    glGenBuffers(1, &ebo_);
    glBindVertexArray(vao_);
    glBindBuffer(GL_ARRAY_BUFFER, vbo_);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, ebo_);
    const GLsizei stride = 6 * sizeof(float);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, stride, nullptr);
    glEnableVertexAttribArray(1);
    glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, stride,
                          reinterpret_cast<const void*>(static_cast<std::uintptr_t>(3 * sizeof(float))));
  } else {
    glBindVertexArray(vao_);
    glBindBuffer(GL_ARRAY_BUFFER, vbo_);
  }
  const GLenum usage = dynamic ? GL_DYNAMIC_DRAW : GL_STATIC_DRAW;
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(vertices.size() * sizeof(float)), vertices.data(), usage);
  glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(indices.size() * sizeof(std::uint32_t)),
               indices.data(), usage);
  has_colours_ = !colours.empty() && colours.size() / 3 == vertices.size() / 6;
  if (has_colours_) {
    if (cbo_ == 0) glGenBuffers(1, &cbo_);
    glBindBuffer(GL_ARRAY_BUFFER, cbo_);
    glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(colours.size() * sizeof(float)), colours.data(), usage);
    glEnableVertexAttribArray(2);
    glVertexAttribPointer(2, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), nullptr);
  } else {
    glDisableVertexAttribArray(2);
  }
  glBindVertexArray(0);
  count_ = indices.size();
  primitive_ = primitive;
}

void Mesh::draw() const {
  if (count_ == 0) return;
  glBindVertexArray(vao_);
  glDrawElements(primitive_, static_cast<GLsizei>(count_), GL_UNSIGNED_INT, nullptr);
  glBindVertexArray(0);
}

Framebuffer::~Framebuffer() { release(); }

void Framebuffer::release() {
  if (fbo_ != 0) glDeleteFramebuffers(1, &fbo_);
  if (colour_ != 0) glDeleteRenderbuffers(1, &colour_);
  if (depth_ != 0) glDeleteRenderbuffers(1, &depth_);
  fbo_ = colour_ = depth_ = 0;
  width_ = height_ = 0;
}

void Framebuffer::ensure(int width, int height) {
  if (fbo_ != 0 && width == width_ && height == height_) return;
  release();
  glGenFramebuffers(1, &fbo_);
  glGenRenderbuffers(1, &colour_);
  glGenRenderbuffers(1, &depth_);
  glBindRenderbuffer(GL_RENDERBUFFER, colour_);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, width, height);
  glBindRenderbuffer(GL_RENDERBUFFER, depth_);
  glRenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, width, height);
  glBindFramebuffer(GL_FRAMEBUFFER, fbo_);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, colour_);
  glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
  if (status != GL_FRAMEBUFFER_COMPLETE) {
    release();
    throw ResourceError("viewer: the off-screen framebuffer " + std::to_string(width) + "x" + std::to_string(height) +
                        " is incomplete (status " + std::to_string(status) + ")");
  }
  width_ = width;
  height_ = height;
}

}  // namespace hc::viewer::gl
