#pragma once
// The frames of a project (its linear cache) or of a plain clip: their size, count and rate
// for the panels, and the frames themselves for the viewer's renderer (which caches what it
// shows: view_renderer.h).
#include <memory>
#include <string>

#include "io/clip.h"
#include "project/project.h"

namespace refocus {

class FrameSource {
  public:
    // Opens a project folder / project.json, or any clip ClipReader accepts.
    explicit FrameSource(const std::string& path);
    int width() const { return m_width; }
    int height() const { return m_height; }
    int frames() const { return m_frames; }
    double fps() const { return m_fps; }
    const std::string& label() const { return m_label; }
    Image linear(int index);

  private:
    std::unique_ptr<Project> m_project;
    std::unique_ptr<ClipReader> m_clip;
    int m_width = 0, m_height = 0, m_frames = 0;
    double m_fps = 24.0;
    std::string m_label;
};

}  // namespace refocus
