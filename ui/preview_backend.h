#pragma once
// How the viewer's renderer turns a frame's layers into a picture: the GLSL passes
// (gl_preview.h) on a GL context of the renderer's own, or their CPU twin (engine/render/
// preview.h). Both read the same kernel tables; tests/gl/test_gl_preview.cpp holds them equal.
// The GLSL passes are the default, software GL (llvmpipe) included: there they cache the sample's
// 30 refocused frames in 15.5 s against the CPU twin's 23.6 s (docs/benchmarks.md); the CPU twin
// is the fallback when no GL context can be had, and a choice in View > Preview renderer.
#include <memory>
#include <string>

#include "edit/recompose.h"
#include "gl_preview.h"
#include "render/preview.h"

namespace refocus {

// The artist's edited atlases (edit over the fit's atlases); bg empty until the fit's atlases
// arrived. `version` changes with every stroke, undo or import.
struct EditAtlases {
    std::shared_ptr<const Image> bg, fg;
    int64_t version = -1;
};

class PreviewBackend {
  public:
    virtual ~PreviewBackend() = default;
    virtual const char* name() const = 0;
    // The frame through `lens` (depth == nullptr or lens.aperture == 0: the sharp composite),
    // with the edits drawn in through the frame's UV maps (paper Fig. 1). Linear RGB.
    virtual Image render(const FrameMaps& maps, const EditAtlases& edits, const PreviewDepth* depth,
                         const PreviewLens& lens) = 0;
    // The GLSL passes' depth of field: Fast (playback and scrubbing) or Exact. The CPU twin
    // renders the exact gather whatever is asked (it has no fast path).
    virtual void set_quality(PreviewQuality) {}
};

std::unique_ptr<PreviewBackend> make_cpu_preview(int threads);
// Needs a GL 3.3 context current on the calling thread for the backend's whole life.
std::unique_ptr<PreviewBackend> make_gl_preview();

// True for GL renderers that run on the CPU (llvmpipe, softpipe, swrast).
bool is_software_gl(const std::string& renderer);

}  // namespace refocus
