// scans2rawlog: write laser scans + odometry as an MRPT rawlog in the
// "actions / sensory frames" format that MRPT's rbpf-slam app reads.
//
// Why this exists: MRPT 2.5's carmen2rawlog writes the newer observations-only
// format (CObservationOdometry + CObservation2DRangeScan), and rbpf-slam 2.5.8
// dereferences a null action on it (segfault). This tool writes, per scan, a
// CActionCollection holding one CActionRobotMovement2D (the odometry increment since
// the previous scan, Gaussian motion model) followed by a CSensoryFrame holding
// the CObservation2DRangeScan, which is the format of MRPT's own example rawlogs.
//
// Input (written by benchmarks/grid_vs_mrpt.py from jaxslam's CARMEN reader, so
// both SLAM systems see exactly the same scans, geometry and validity):
//   line 1:  n_scans n_beams start_angle resolution max_range laser_x laser_y laser_theta
//   then one line per scan: t odom_x odom_y odom_theta r_1 .. r_n   (r <= 0: invalid)
// Angles in rad, beam i at start_angle + i * resolution in the laser frame.
//
// Usage: scans2rawlog IN.txt OUT.rawlog a1 a2 a3 a4 minStdXY minStdPHI_deg
//   (CActionRobotMovement2D::TMotionModelOptions::TOptions_GaussianModel:
//   std_xy = minStdXY + a1 * dist + a2 * |dphi|, std_phi = minStdPHI + a3 * dist +
//   a4 * |dphi|, SI units with angles in rad; only minStdPHI is given in degrees).
//
// Build: g++ -O2 -std=c++17 scans2rawlog.cpp $(include dirs of mrpt-obs etc.)
//   -lmrpt-obs -lmrpt-poses -lmrpt-serialization -lmrpt-io -lmrpt-system
//   -lmrpt-math -lmrpt-core   (grid_vs_mrpt.py does this for you).

#include <mrpt/core/Clock.h>
#include <mrpt/io/CFileGZOutputStream.h>
#include <mrpt/obs/CActionCollection.h>
#include <mrpt/obs/CActionRobotMovement2D.h>
#include <mrpt/obs/CObservation2DRangeScan.h>
#include <mrpt/obs/CSensoryFrame.h>
#include <mrpt/poses/CPose2D.h>
#include <mrpt/poses/CPose3D.h>
#include <mrpt/serialization/CArchive.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

int main(int argc, char** argv)
{
	if (argc != 9)
	{
		std::cerr << "usage: " << argv[0]
				  << " IN.txt OUT.rawlog a1 a2 a3 a4 minStdXY minStdPHI_deg\n";
		return 2;
	}
	std::ifstream in(argv[1]);
	if (!in)
	{
		std::cerr << "cannot open " << argv[1] << "\n";
		return 1;
	}
	size_t n_scans = 0, n_beams = 0;
	double start_angle, resolution, max_range, lx, ly, lth;
	if (!(in >> n_scans >> n_beams >> start_angle >> resolution >> max_range >>
		  lx >> ly >> lth) ||
		n_beams < 2)
	{
		std::cerr << "bad header in " << argv[1] << "\n";
		return 1;
	}

	mrpt::obs::CActionRobotMovement2D::TMotionModelOptions motion;
	motion.modelSelection = mrpt::obs::CActionRobotMovement2D::mmGaussian;
	motion.gaussianModel.a1 = std::atof(argv[3]);
	motion.gaussianModel.a2 = std::atof(argv[4]);
	motion.gaussianModel.a3 = std::atof(argv[5]);
	motion.gaussianModel.a4 = std::atof(argv[6]);
	motion.gaussianModel.minStdXY = std::atof(argv[7]);
	motion.gaussianModel.minStdPHI = std::atof(argv[8]) * M_PI / 180.0;

	// MRPT spreads n beams evenly over [-aperture/2, +aperture/2] (right to
	// left). With aperture = (n-1)*resolution the beam spacing equals ours; the
	// remaining constant shift goes into the sensor yaw.
	const double aperture = (n_beams - 1) * resolution;
	const double yaw_shift = start_angle + aperture / 2;
	const mrpt::poses::CPose3D sensor_pose(lx, ly, 0.0, lth + yaw_shift, 0.0, 0.0);

	mrpt::io::CFileGZOutputStream out_file(argv[2]);
	auto out = mrpt::serialization::archiveFrom(out_file);

	mrpt::poses::CPose2D previous_odom;
	for (size_t k = 0; k < n_scans; k++)
	{
		double t, ox, oy, oth;
		if (!(in >> t >> ox >> oy >> oth))
		{
			std::cerr << "scan " << k << ": cannot read the pose\n";
			return 1;
		}
		const mrpt::poses::CPose2D odom(ox, oy, oth);
		const auto stamp = mrpt::Clock::fromDouble(t);

		auto scan = mrpt::obs::CObservation2DRangeScan::Create();
		scan->sensorLabel = "FLASER";
		scan->timestamp = stamp;
		scan->aperture = static_cast<float>(aperture);
		scan->rightToLeft = true;
		scan->maxRange = static_cast<float>(max_range);
		scan->sensorPose = sensor_pose;
		scan->resizeScan(n_beams);
		for (size_t i = 0; i < n_beams; i++)
		{
			double r;
			if (!(in >> r))
			{
				std::cerr << "scan " << k << ": cannot read range " << i << "\n";
				return 1;
			}
			const bool valid = std::isfinite(r) && r > 0 && r < max_range;
			scan->setScanRange(i, valid ? static_cast<float>(r) : 0.0f);
			scan->setScanRangeValidity(i, valid);
		}

		mrpt::obs::CActionRobotMovement2D move;
		move.computeFromOdometry(
			k == 0 ? mrpt::poses::CPose2D() : odom - previous_odom, motion);
		move.timestamp = stamp;
		mrpt::obs::CActionCollection actions;
		actions.insert(move);

		mrpt::obs::CSensoryFrame frame;
		frame.insert(scan);

		out << actions << frame;
		previous_odom = odom;
	}
	return 0;
}
