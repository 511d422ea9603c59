#pragma once
// A headless OpenGL core context on OSMesa (llvmpipe) for the GL tests and the preview
// benchmark. Header-only and used only by binaries that link libOSMesa instead of libGL.
#include <GL/osmesa.h>

#include <string>
#include <vector>

#include "util/error.h"

namespace refocus {

class HeadlessGl {
  public:
    // A `major`.`minor` core-profile context with a tiny default framebuffer (every pass renders
    // into its own textures), made current on the calling thread.
    explicit HeadlessGl(int major = 3, int minor = 3) : m_buffer(16 * 16 * 4) {
        const int attribs[] = {OSMESA_FORMAT,
                               OSMESA_RGBA,
                               OSMESA_DEPTH_BITS,
                               0,
                               OSMESA_STENCIL_BITS,
                               0,
                               OSMESA_ACCUM_BITS,
                               0,
                               OSMESA_PROFILE,
                               OSMESA_CORE_PROFILE,
                               OSMESA_CONTEXT_MAJOR_VERSION,
                               major,
                               OSMESA_CONTEXT_MINOR_VERSION,
                               minor,
                               0};
        m_ctx = OSMesaCreateContextAttribs(attribs, nullptr);
        if (!m_ctx)
            throw Error("OSMesa: cannot create a GL " + std::to_string(major) + "." +
                        std::to_string(minor) + " core context");
        if (!OSMesaMakeCurrent(m_ctx, m_buffer.data(), GL_UNSIGNED_BYTE, 16, 16))
            throw Error("OSMesa: cannot make the context current");
    }
    ~HeadlessGl() {
        if (m_ctx) OSMesaDestroyContext(m_ctx);
    }
    HeadlessGl(const HeadlessGl&) = delete;
    HeadlessGl& operator=(const HeadlessGl&) = delete;

    static std::string renderer() {
        const GLubyte* r = glGetString(GL_RENDERER);
        const GLubyte* v = glGetString(GL_VERSION);
        return std::string(r ? reinterpret_cast<const char*>(r) : "?") + " / " +
               (v ? reinterpret_cast<const char*>(v) : "?");
    }

  private:
    OSMesaContext m_ctx = nullptr;
    std::vector<unsigned char> m_buffer;
};

}  // namespace refocus
